"""The PLC handshake over Modbus registers: a real pymodbus client against the served agent and a simulated EC66
(its real JSON-RPC protocol on loopback): trigger, busy, done, result values, error codes, busy refused."""

from __future__ import annotations

import time

import pytest
import yaml
from pymodbus.client import ModbusTcpClient

from conftest import ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.plc.jobs import ERROR_BAD_REQUEST, ERROR_BUSY, RobotJobs
from payload_agent.plc.modbus_server import ModbusHandshakeServer, words_float
from payload_agent.recording.state import RobotState
from payload_agent.session.simulation import SimulatedCell
from payload_agent.tools import library
from payload_agent.tools.library import ToolEntry

WAIT_S = 60.0
BUSY, DONE, ERROR = 1, 2, 4


@pytest.fixture
def plc(tmp_path):
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    config = parse_config(data, source="test")
    db = library.tool_library_path(RobotState.for_config(config).root)
    library.store(db, config.robot.name, ToolEntry("gripper", 1.75, (10.0, -5.0, 90.0), 0.002, (0.5, 0.5, 0.6),
                                                   number=4))
    cell = SimulatedCell(config).start()
    jobs = RobotJobs(config, cell=cell)
    server = ModbusHandshakeServer(jobs, port=0).start()
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=10)
    assert client.connect()
    try:
        yield client, cell
    finally:
        client.close()
        jobs.wait(WAIT_S)
        server.stop()
        cell.close()


def _inputs(client) -> list[int]:
    r = client.read_input_registers(0, count=30, device_id=1)
    assert not r.isError(), r
    return list(r.registers)


def _wait(client, mask, set_: bool = True) -> list[int]:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        regs = _inputs(client)
        if bool(regs[0] & mask) == set_:
            return regs
        time.sleep(0.05)
    raise AssertionError(f"status bits {mask} did not become {set_} within {WAIT_S} s")


def _write(client, address, values):
    r = client.write_registers(address, values, device_id=1)
    assert not r.isError(), r


def test_apply_handshake_busy_refused_and_result_registers(plc):
    client, cell = plc
    cell.controller.inject_fault("slow_reply")  # the controller answers late: the Apply job stays busy
    _write(client, 0, [3, 1, 4])  # Command Apply, Execute, ToolNumber 4 (gripper)
    regs = _wait(client, BUSY)
    assert regs[2] == 1  # State busy
    _write(client, 1, [0])  # Execute falls while busy: the job runs on
    _write(client, 0, [2, 1, 4])  # a second trigger (Verify) while busy: refused, nothing started
    regs = _wait(client, ERROR)
    assert regs[1] == ERROR_BUSY and not regs[0] & BUSY
    cell.controller.clear_faults()
    _write(client, 0, [3, 0])  # back to the Apply block, Execute low: it finishes, then its outputs clear
    deadline = time.monotonic() + WAIT_S
    while _inputs(client)[2] == 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    _write(client, 1, [1])  # Apply again, healthy controller
    regs = _wait(client, DONE)
    assert not regs[0] & ERROR and regs[1] == 0 and regs[3] == 3 and regs[4] == 4 and regs[5] == 4
    assert words_float(regs[6:8]) == pytest.approx(1.75)
    assert [words_float(regs[i:i + 2]) for i in (8, 10, 12)] == pytest.approx([10.0, -5.0, 90.0])
    assert words_float(regs[22:24]) == pytest.approx(1.75)  # the flange load now set
    assert cell.controller.payload_setting()["m"] == pytest.approx(1.75)  # really on the controller
    _write(client, 1, [0])
    regs = _wait(client, DONE, set_=False)
    assert regs[0] == 0 and regs[1] == 0


def test_error_codes(plc):
    client, cell = plc
    _write(client, 0, [3, 1, 9])  # Apply a tool number the library does not have
    regs = _wait(client, ERROR)
    assert regs[1] == ERROR_BAD_REQUEST and regs[2] == 0  # refused before any job
    _write(client, 0, [7, 0, 0])
    _write(client, 1, [1])  # an unknown command
    assert _wait(client, ERROR)[1] == ERROR_BAD_REQUEST
    _write(client, 0, [3, 0, 4])
    cell.controller.inject_fault("leave_remote")  # the pendant took control: the write cannot take
    _write(client, 1, [1])
    regs = _wait(client, ERROR)
    assert regs[1] == 6 and regs[4] == 5  # communication failure; LastVerdict failed
    r = client.write_registers(10, [1], device_id=1)  # outside the holding registers
    assert r.isError()
