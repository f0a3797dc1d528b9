"""The PLC handshake over Modbus TCP registers (pymodbus server), for PLCs without OPC UA.

One robot per server (one ``RobotJobs``); every unit id is answered. Addresses are 0-based register numbers.
Floats are IEEE-754 float32 in two registers, high word first (big-endian, the common Modbus convention).

Holding registers (the PLC writes; reading them back is allowed):

==== ============ ==========================================================================
0    Command      1 Identify, 2 Verify, 3 Apply
1    Execute      0/1: a rising edge (0 -> 1) starts Command; a falling edge clears Done/Error
2    ToolNumber   the library tool's number (``tools`` ... ``number``); 0: Verify compares with the
                  controller's current setting, Identify records an unnamed tool. Identify of a number
                  the library does not have stores the tool as ``tool-<n>`` with that number
==== ============ ==========================================================================

Input registers (the agent writes; read with function 4):

======= ================ =================================================================
0       Status           bit 0 Busy, bit 1 Done, bit 2 Error (of the command in register 0)
1       ErrorID          the command line's exit code (7: another tool), 100 busy (start refused),
                         101 bad request (unknown command or tool number)
2       State            0 idle, 1 busy
3       LastCommand      1..3 (0: none yet)
4       LastVerdict      0 none, 1 match, 2 mismatch, 3 identified, 4 applied, 5 failed
5       LastToolNumber   0 when the tool has no number
6-7     LastMass         kg
8-13    LastCoM          x, y, z, mm (flange frame)
14-15   LastMassStd      kg (standard uncertainty)
16-21   LastCoMStd       x, y, z, mm
22-23   FlangeLoadMass   kg: the payload this agent last wrote or verified
24-29   FlangeLoadCoM    x, y, z, mm
======= ================ =================================================================

Modbus TCP has no authentication or encryption: the server binds where the serve config says (loopback by
default) and belongs on the cell's own network segment only.
"""

from __future__ import annotations

import asyncio
import math
import struct
import threading

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from payload_agent.plc.jobs import COMMANDS, ERROR_BAD_REQUEST, RobotJobs
from payload_agent.recording.state import RobotState
from payload_agent.tools import library

HOLDING_SIZE = 3
INPUT_SIZE = 30
VERDICTS = {"": 0, "match": 1, "mismatch": 2, "identified": 3, "applied": 4, "failed": 5}


def float_words(value: float) -> list[int]:
    hi, lo = struct.unpack(">HH", struct.pack(">f", float(value)))
    return [hi, lo]


def words_float(words: list[int]) -> float:
    return struct.unpack(">f", struct.pack(">HH", int(words[0]), int(words[1])))[0]


class HandshakeRegisters:
    """The pymodbus datastore of the interface above (``device_ids``, ``async_getValues``, ``async_setValues``)."""

    def __init__(self, jobs: RobotJobs):
        self.jobs = jobs
        self.holding = [0] * HOLDING_SIZE
        self._lock = threading.Lock()
        self._errors: dict[str, tuple[int, str]] = {}  # refusals of requests that never became a job

    def device_ids(self) -> list[int]:
        return [0]

    def _tool(self, command: str, number: int) -> tuple[str, int | None] | None:
        if number == 0:
            return "", None
        db = library.tool_library_path(RobotState.for_config(self.jobs.config).root)
        entry = library.by_number(db, self.jobs.config.robot.name, number)
        if entry is not None:
            return entry.name, None
        if command == "Identify":
            return f"tool-{number}", number
        return None

    def _on_execute(self, rising: bool) -> None:
        code = self.holding[0]
        command = COMMANDS[code - 1] if 1 <= code <= len(COMMANDS) else None
        if command is None:
            if rising:
                self._errors["?"] = (ERROR_BAD_REQUEST, f"register 0 (Command) holds {code}: expected 1, 2 or 3")
            else:
                self._errors.pop("?", None)
            return
        if not rising:
            self._errors.pop(command, None)
            self.jobs.reset(command)
            return
        tool = self._tool(command, self.holding[2])
        if tool is None:
            self._errors[command] = (ERROR_BAD_REQUEST, f"register 2 (ToolNumber) holds {self.holding[2]}: no library "
                                                        "tool has this number")
            return
        self._errors.pop(command, None)
        self.jobs.start(command, tool[0], tool[1])

    def _inputs(self) -> list[int]:
        jobs = self.jobs
        code = self.holding[0]
        command = COMMANDS[code - 1] if 1 <= code <= len(COMMANDS) else "?"
        if command in self._errors:
            busy, done, error, error_id = False, False, True, self._errors[command][0]
        elif command == "?":
            busy = done = error = False
            error_id = 0
        else:
            hs = jobs.handshakes[command]
            busy, done, error, error_id = hs.busy, hs.done, hs.error, hs.error_id
        last = jobs.last
        db = library.tool_library_path(RobotState.for_config(jobs.config).root)
        entry = library.get(db, jobs.config.robot.name, last.tool) if last.tool else None
        words = [int(busy) | int(done) << 1 | int(error) << 2, int(error_id), int(jobs.busy),
                 COMMANDS.index(last.command) + 1 if last.command in COMMANDS else 0, VERDICTS.get(last.verdict, 0),
                 entry.number if entry is not None and entry.number else 0]
        for v in (last.mass_kg, *last.cog_mm, last.mass_std_kg, *last.cog_std_mm, jobs.load.mass_kg, *jobs.load.cog_mm):
            words += float_words(v if math.isfinite(v) else math.nan)
        return words

    async def async_getValues(self, device_id: int, func_code: int, address: int, count: int = 1):
        with self._lock:
            if func_code == 3:
                table = self.holding
            elif func_code == 4:
                table = self._inputs()
            else:
                return ExcCodes.ILLEGAL_FUNCTION
            if address < 0 or address + count > len(table):
                return ExcCodes.ILLEGAL_ADDRESS
            return list(table[address:address + count])

    async def async_setValues(self, device_id: int, func_code: int, address: int, values):
        values = list(values) if isinstance(values, (list, tuple)) else [values]
        with self._lock:
            if func_code not in (6, 16):
                return ExcCodes.ILLEGAL_FUNCTION
            if address < 0 or address + len(values) > HOLDING_SIZE:
                return ExcCodes.ILLEGAL_ADDRESS
            before = self.holding[1]
            self.holding[address:address + len(values)] = [int(v) & 0xFFFF for v in values]
            after = self.holding[1]
            if bool(after) != bool(before):
                self._on_execute(bool(after))
        return None


class ModbusHandshakeServer:
    """The register interface on its own asyncio loop in a thread; ``port`` is known after ``start``."""

    def __init__(self, jobs: RobotJobs, host: str = "127.0.0.1", port: int = 5020):
        self.registers = HandshakeRegisters(jobs)
        self.host, self.port = host, port
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True, name="modbus-handshake")
        self._server = None

    async def _start(self) -> None:
        dummy = SimDevice(0, simdata=[SimData(0, datatype=DataType.UINT16)])
        server = ModbusTcpServer(dummy, address=(self.host, self.port))
        server.context = self.registers  # these registers answer every request
        await server.serve_forever(background=True)
        self._server = server
        self.port = server.transport.sockets[0].getsockname()[1]

    def start(self, timeout_s: float = 10.0) -> "ModbusHandshakeServer":
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self._loop).result(timeout_s)
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._server is not None:
            try:
                asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop).result(timeout_s)
            except Exception:
                pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout_s)
