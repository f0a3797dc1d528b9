"""The fake UR controller against the real ur_rtde client (and raw sockets for the strictness checks)."""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import threading
import time

import numpy as np
import pytest

rtde_receive = pytest.importorskip("rtde_receive", reason="ur-rtde wheel not installed (CPython 3.11/3.12)")
pytest.importorskip("rtde_control")

from payload_agent.drivers.ur_rtde.control import ControlChannel  # noqa: E402
from payload_agent.errors import RobotNotReadyError  # noqa: E402
from payload_agent.fakes import ur_rtde_protocol as rp  # noqa: E402
from payload_agent.fakes.physics import PayloadTruth  # noqa: E402
from payload_agent.fakes.ur import DEFAULT_GAINS_NM_PER_A, FakeURController  # noqa: E402

HOME = [0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0]


@pytest.fixture(scope="module")
def ur():
    with FakeURController(time_scale=1.0, current_noise_a=0.05) as fake:
        yield fake


@pytest.fixture
def clean(ur):
    """Every test starts from a healthy, idle controller."""
    ur.reset_safety()
    ur.set_remote_control(True)
    yield ur
    ur.reset_safety()


# -- a raw RTDE client for the strictness checks ------------------------------------------------------

class RawRTDE:
    def __init__(self, host: str):
        self.sock = socket.create_connection((host, 30004), timeout=3)

    def send(self, kind: int, payload: bytes = b"") -> None:
        self.sock.sendall(rp.pack(kind, payload))

    def recv(self) -> tuple[int, bytes]:
        _, kind, payload = rp.recv_package(self.sock)
        return kind, payload

    def request(self, kind: int, payload: bytes = b"") -> tuple[int, bytes]:
        self.send(kind, payload)
        return self.recv()

    def negotiate(self, version: int = 2) -> int:
        kind, payload = self.request(rp.REQUEST_PROTOCOL_VERSION, struct.pack(">H", version))
        assert kind == rp.REQUEST_PROTOCOL_VERSION
        return payload[0]

    def setup_outputs(self, names, freq=500.0) -> tuple[int, list[str]]:
        kind, payload = self.request(rp.CONTROL_PACKAGE_SETUP_OUTPUTS,
                                     struct.pack(">d", freq) + ",".join(names).encode())
        assert kind == rp.CONTROL_PACKAGE_SETUP_OUTPUTS
        return payload[0], payload[1:].decode().split(",")

    def close(self) -> None:
        self.sock.close()


def test_protocol_version_and_controller_version(ur):
    c = RawRTDE(ur.host)
    try:
        assert c.negotiate(2) == 1
        assert c.negotiate(2) == 1  # repeats are accepted
        assert c.negotiate(3) == 0  # unknown protocol version refused
        kind, payload = c.request(rp.GET_URCONTROL_VERSION)
        assert kind == rp.GET_URCONTROL_VERSION
        assert struct.unpack(">IIII", payload) == (5, 11, 1, 108318)
    finally:
        c.close()


def test_output_setup_types_and_not_found(ur):
    c = RawRTDE(ur.host)
    try:
        c.negotiate()
        rid, types = c.setup_outputs(["timestamp", "actual_q", "joint_mode", "payload_cog", "runtime_state",
                                      "safety_status_bits", "actual_digital_input_bits"])
        assert rid == 1
        assert types == ["DOUBLE", "VECTOR6D", "VECTOR6INT32", "VECTOR3D", "UINT32", "UINT32", "UINT64"]
        rid, types = c.setup_outputs(["timestamp", "no_such_variable"])
        assert rid == 0 and types == ["DOUBLE", "NOT_FOUND"]
        # a PolyScope 5.23 field on a 5.11 controller
        rid, types = c.setup_outputs(["actual_current_as_torque"])
        assert rid == 0 and types == ["NOT_FOUND"]
    finally:
        c.close()


def test_ur_rtde_reports_unknown_variable(ur):
    with pytest.raises(RuntimeError, match="no_such_variable"):
        rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "no_such_variable"])


def test_input_registers_in_use_by_another_client(ur):
    a, b = RawRTDE(ur.host), RawRTDE(ur.host)
    try:
        a.negotiate()
        b.negotiate()
        kind, payload = a.request(rp.CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_40,input_double_register_40")
        assert payload[0] == 1 and payload[1:] == b"INT32,DOUBLE"
        kind, payload = b.request(rp.CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_40")
        assert payload[0] == 0 and payload[1:] == b"IN_USE"
        kind, payload = b.request(rp.CONTROL_PACKAGE_SETUP_INPUTS, b"no_such_input")
        assert payload[0] == 0 and payload[1:] == b"NOT_FOUND"
    finally:
        a.close()
        b.close()


def test_bad_framing_and_unknown_packages(ur):
    c = RawRTDE(ur.host)
    try:
        c.negotiate()
        # unknown package type: the controller answers with an error text message
        kind, payload = c.request(ord("X"))
        assert kind == rp.TEXT_MESSAGE and b"unknown package type" in payload
        # data package for an input recipe that does not exist
        kind, payload = c.request(rp.DATA_PACKAGE, bytes([9]) + struct.pack(">i", 1))
        assert kind == rp.TEXT_MESSAGE and b"unknown input recipe" in payload
        # data package of the wrong length
        _, p = c.request(rp.CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_41")
        kind, payload = c.request(rp.DATA_PACKAGE, bytes([p[0]]) + struct.pack(">ii", 1, 2))
        assert kind == rp.TEXT_MESSAGE and b"expected 5" in payload
        # start without an output recipe is refused
        kind, payload = c.request(rp.CONTROL_PACKAGE_START)
        assert kind == rp.CONTROL_PACKAGE_START and payload == b"\x00"
        # a header whose size is smaller than the header itself: the controller hangs up
        c.sock.sendall(struct.pack(">HB", 1, rp.REQUEST_PROTOCOL_VERSION))
        assert c.sock.recv(100) == b""
    finally:
        c.close()
    assert any("bad framing" in e for e in ur.rtde_errors)


def test_raw_stream_rate_500hz_and_decimation(ur):
    """A 500 Hz recipe gets a package for every 2 ms control cycle, 125 Hz every fourth (in controller time).

    The wall-clock rate is printed, not asserted: a busy machine slows the simulated clock down.
    """
    c = RawRTDE(ur.host)
    try:
        c.negotiate()
        c.setup_outputs(["timestamp", "actual_q", "actual_current"], 500.0)
        _, ok = c.request(rp.CONTROL_PACKAGE_START)
        assert ok == b"\x01"
        st = rp.recipe_struct(["DOUBLE", "VECTOR6D", "VECTOR6D"])
        stamps = []
        t0 = time.monotonic()
        while len(stamps) < 500:
            kind, payload = c.recv()
            assert kind == rp.DATA_PACKAGE and payload[0] == 1 and len(payload) == st.size
            stamps.append(st.unpack(payload)[1])
        wall = time.monotonic() - t0
        _, ok = c.request(rp.CONTROL_PACKAGE_PAUSE)
    finally:
        c.close()
    print(f"\nraw RTDE: 500 packages in {wall:.3f} s wall = {499 / wall:.0f} Hz")
    assert np.allclose(np.diff(stamps), 0.002, atol=1e-9)  # every simulated cycle, none skipped

    c = RawRTDE(ur.host)
    try:
        c.negotiate()
        c.setup_outputs(["timestamp"], 125.0)
        c.request(rp.CONTROL_PACKAGE_START)
        stamps = [struct.unpack(">Bd", c.recv()[1])[1] for _ in range(20)]
    finally:
        c.close()
    assert np.allclose(np.diff(stamps), 0.008, atol=1e-9)


def test_receive_interface_streams_in_sim_time(ur):
    r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "actual_q", "actual_current", "robot_mode",
                                                            "safety_mode", "safety_status_bits", "runtime_state"])
    try:
        assert r.isConnected()
        w0 = time.monotonic()
        t0 = r.getTimestamp()
        ur.wait_ticks(100)
        time.sleep(0.02)
        t1 = r.getTimestamp()
        dt_wall = time.monotonic() - w0
        # the controller's clock: simulated time in 2 ms cycles, never ahead of wall time at time_scale 1
        # (a busy machine may slow it down, never speed it up)
        assert 0.1 <= t1 - t0 <= dt_wall + 0.01
        assert abs(t1 / 0.002 - round(t1 / 0.002)) < 1e-6 and t1 <= ur.robot.now() + 1e-9
        assert r.getRobotMode() == 7 and r.getSafetyMode() == 1 and r.getSafetyStatusBits() == 1
        assert len(r.getActualQ()) == 6
        # actual_current = torque / gain (+ noise): compare with the simulation's torque
        tau = ur.robot.snapshot().torque_nm
        cur = np.asarray(r.getActualCurrent())
        assert np.allclose(cur, tau / np.asarray(DEFAULT_GAINS_NM_PER_A), atol=0.4)
    finally:
        del r  # its destructor disconnects (once: an explicit disconnect() first costs another 0.5 s)


def test_dashboard(ur):
    with socket.create_connection((ur.host, 29999), timeout=3) as s:
        f = s.makefile("rwb")
        assert f.readline() == b"Connected: Universal Robots Dashboard Server\n"

        def ask(cmd: str) -> str:
            f.write(cmd.encode() + b"\n")
            f.flush()
            return f.readline().decode().rstrip("\n")

        assert "5.11.1.108318" in ask("PolyscopeVersion")
        assert ask("get serial number").isdigit()
        assert ask("is in remote control") == "true"
        assert ask("robotmode") == "Robotmode: RUNNING"
        assert ask("safetymode") == "Safetymode: NORMAL"
        assert ask("get robot model") == "UR5"
        assert ask("bogus") == "could not understand: 'bogus'"


@contextlib.contextmanager
def control_interface(host: str, upper_range_registers: bool = False):
    """ur-rtde's real RTDEControlInterface, held in the driver's worker process (``ControlChannel``), never in
    the test process: ur-rtde 1.6.5's receive thread can dereference a reset socket when its connection ends
    (``RTDE::isDataAvailable``, SIGSEGV; docs/sources.md), and in a pytest-xdist worker that crash killed the
    worker and hung the suite. Requests are the worker's: ("moveJ", …), ("progress",), ("stopJ", …), …"""
    channel = ControlChannel(host, 500.0, upper_range_registers)
    try:
        channel.get(lambda: "")
        yield channel
    finally:
        channel.discard()


def call(channel: ControlChannel, op: str, *args, timeout_s: float = 10.0):
    """One ur-rtde call in the worker; its reply also refreshes channel.connected / channel.program_running."""
    return channel.request(op, *args, timeout_s=timeout_s)


def async_running(channel: ControlChannel) -> bool:
    return call(channel, "progress")[1]


def test_control_interface_move_stop_and_payload(clean):
    ur = clean
    r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "actual_q", "payload", "payload_cog",
                                                            "runtime_state"])
    try:
        with control_interface(ur.host) as c:
            assert c.connected and c.program_running
            assert "rtde_control" in ur.programs_run
            target = [0.1, -1.45, 1.45, -1.65, -1.5, 0.05]
            assert call(c, "moveJ", target, 1.0, 3.0)  # synchronous: returns when the move is done
            deadline = time.monotonic() + 2.0  # the receive interface's packages may trail the control interface's
            while not np.allclose(r.getActualQ(), target, atol=1e-9) and time.monotonic() < deadline:
                time.sleep(0.002)
            assert np.allclose(r.getActualQ(), target, atol=1e-9)
            assert call(c, "setPayload", 1.25, [0.01, -0.02, 0.07])
            eventually(lambda: r.getPayload() == pytest.approx(1.25))
            assert r.getPayload() == pytest.approx(1.25)
            assert r.getPayloadCog() == pytest.approx([0.01, -0.02, 0.07])
            assert ur.controller_payload[0] == pytest.approx(1.25)
            # async move, then stopJ halts it short of the target
            assert call(c, "moveJ", HOME, 0.3, 1.0, True)
            time.sleep(0.3)
            assert async_running(c)
            call(c, "stopJ", 2.0)
            time.sleep(0.05)
            q = np.asarray(r.getActualQ())
            assert not np.allclose(q, HOME, atol=1e-3)
            assert not async_running(c)
            call(c, "stopScript")
            assert not c.program_running
            deadline = time.monotonic() + 2.0
            while r.getRuntimeState() != 1 and time.monotonic() < deadline:
                time.sleep(0.002)
            assert r.getRuntimeState() == 1
    finally:
        del r  # its destructor disconnects (once: an explicit disconnect() first costs another 0.5 s)
    assert ur.script_errors == []


def test_control_interface_needs_remote_control(clean):
    clean.set_remote_control(False)
    with pytest.raises(RobotNotReadyError, match="Remote Control.*Please enable remote control"):
        with control_interface(clean.host):
            pass


def test_plain_script_on_port_30002(clean):
    ur = clean
    target = [0.05, -1.5, 1.5, -1.6, -1.55, 0.02]
    with socket.create_connection((ur.host, 30002), timeout=3) as s:
        s.sendall(f"movej({target}, a=3.0, v=1.5)\n".encode())
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            st = ur.robot.snapshot()
            if not st.moving and np.allclose(st.q, target, atol=1e-9):
                break
            time.sleep(0.02)
        assert np.allclose(ur.robot.snapshot().q, target, atol=1e-9)
        n_errors = len(ur.script_errors)
        s.sendall(b"def prog():\n  set_payload(0.8, [0, 0, 0.05])\n  launch_rockets()\nend\n")
        deadline = time.monotonic() + 2
        while len(ur.script_errors) == n_errors and time.monotonic() < deadline:
            time.sleep(0.01)
        assert "launch_rockets" in ur.script_errors[-1]
        assert ur.controller_payload[0] != pytest.approx(0.8)  # the program never ran


def test_protective_stop_and_estop_are_visible(clean):
    ur = clean
    r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "actual_qd", "robot_mode", "safety_mode",
                                                            "safety_status_bits", "runtime_state"])
    stack = contextlib.ExitStack()
    try:
        c = stack.enter_context(control_interface(ur.host))
        assert call(c, "moveJ", [0.6, -1.2, 1.2, -1.4, -1.2, 0.4], 0.5, 2.0, True)
        eventually(lambda: np.max(np.abs(r.getActualQd())) > 0.1)
        ur.trigger_protective_stop()
        eventually(lambda: r.getSafetyStatusBits() & (1 << 2) and r.getRuntimeState() == 1
                   and np.max(np.abs(r.getActualQd())) == 0.0)  # motion stopped, the control script too
        bits = r.getSafetyStatusBits()
        assert bits & (1 << 2) and bits & (1 << 10) and not bits & 1
        assert r.getSafetyMode() == 3
        assert not call(c, "moveJ", HOME, 0.5, 2.0)  # ur_rtde refuses: script not running
        with socket.create_connection((ur.host, 29999), timeout=3) as s:
            f = s.makefile("rwb")
            f.readline()
            f.write(b"unlock protective stop\n")
            f.flush()
            assert f.readline().startswith(b"Cannot unlock protective stop until 5s")
        ur.reset_safety()
        eventually(lambda: r.getSafetyStatusBits() == 1)
        ur.trigger_estop()
        eventually(lambda: r.getSafetyStatusBits() & (1 << 6))
        bits = r.getSafetyStatusBits()
        assert bits & (1 << 6) and bits & (1 << 7)
        assert r.getSafetyMode() == 7 and r.getRobotMode() == 3
    finally:
        stack.close()
        del r  # its destructor disconnects (once: an explicit disconnect() first costs another 0.5 s)


def eventually(predicate, timeout_s: float = 3.0) -> None:
    """Wait for what the receive interface shows (its newest package may trail the controller)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "the RTDE stream never showed it"
        time.sleep(0.002)


def test_tool_change_shows_in_actual_current(clean):
    ur = clean
    r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "actual_current"])

    def mean_current() -> tuple[np.ndarray, np.ndarray]:
        """The mean simulated joint torque and the mean current of 250 distinct packages from now on (a busy
        machine may show one package to several reads, and the receive interface's newest package may
        predate the tool change). Current noise is 0.07 A, about 0.7 N·m a package: the mean of 250 leaves
        about 0.08 N·m on a difference of two, against the 0.3 N·m compared below; the torque (noise
        0.3 N·m at most) is averaged over the first 60 (each snapshot is a call into the controller's process)."""
        seen: dict[float, list[float]] = {}
        torques = []
        t_from = ur.robot.now()
        while len(seen) < 250:
            ts, cur = r.getTimestamp(), r.getActualCurrent()
            if ts > t_from and ts == r.getTimestamp():  # both from one package
                if ts not in seen and len(torques) < 60:
                    torques.append(ur.robot.snapshot().torque_nm)
                seen[ts] = cur
            time.sleep(0.001)
        return np.mean(torques, axis=0), np.mean(list(seen.values()), axis=0)

    try:
        ur.robot.set_payload(None)
        ur.wait_ticks(5)
        empty_tau, empty = mean_current()
        ur.robot.set_payload(PayloadTruth(2.0, (0.0, 0.0, 0.05)))
        ur.wait_ticks(5)
        loaded_tau, loaded = mean_current()
    finally:
        ur.robot.set_payload(None)
        del r  # its destructor disconnects (once: an explicit disconnect() first costs another 0.5 s)
    gains = np.asarray(DEFAULT_GAINS_NM_PER_A)
    assert abs(loaded_tau[1] - empty_tau[1]) > 5.0  # the shoulder carries the extra 2 kg
    assert np.allclose((loaded - empty) * gains, loaded_tau - empty_tau, atol=0.3)


def test_upper_range_registers(clean):
    ur = clean
    with control_interface(ur.host, upper_range_registers=True) as c:
        assert c.program_running
        target = [0.02, -1.55, 1.55, -1.55, -1.55, 0.01]
        assert call(c, "moveJ", target, 1.0, 3.0)
        assert np.allclose(ur.robot.snapshot().q, target, atol=1e-9)
        assert ur.out_int[24] in (1, 2)  # ready / done, in the upper range (offset 24)
        call(c, "stopScript")


# -- the shared loopback TCP server (fakes/tcp_server.py: UR and Elite fakes) -------------------------

def test_tcp_server_ephemeral_port_and_close_unblocks_handlers():

    from payload_agent.fakes.tcp_server import TCPServer

    entered = threading.Event()

    def echo(conn, addr):
        entered.set()
        while True:
            data = conn.recv(100)  # blocks until the peer writes or close() shuts the socket down
            if not data:
                return
            conn.sendall(data.upper())

    server = TCPServer("127.0.0.1", 0, echo, name="test-echo").start()
    assert server.port > 0
    clients = [socket.create_connection(("127.0.0.1", server.port), timeout=2.0) for _ in range(3)]
    clients[0].sendall(b"abc")
    assert clients[0].recv(10) == b"ABC"
    assert entered.wait(2.0)
    deadline = time.monotonic() + 2.0
    while server.connection_count < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert server.connection_count == 3
    t0 = time.monotonic()
    server.close()  # every handler is blocked in recv(): close must wake them all
    assert time.monotonic() - t0 < 1.0 and server.connection_count == 0
    assert all(c.recv(10) == b"" for c in clients)  # the peers see the connection closed
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", server.port), timeout=0.5)
    for c in clients:
        c.close()


def test_tcp_server_reports_handler_bugs_and_names_a_busy_port():

    from payload_agent.fakes.tcp_server import TCPServer

    seen = []

    def broken(conn, addr):
        raise KeyError("bug")

    server = TCPServer("127.0.0.1", 0, broken, name="test-broken", on_error=seen.append).start()
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=2.0) as c:
            assert c.recv(10) == b""  # the connection is closed after the handler failed
        deadline = time.monotonic() + 2.0
        while not seen and time.monotonic() < deadline:
            time.sleep(0.01)
        assert seen and "KeyError" in seen[0] and f"127.0.0.1:{server.port}" in seen[0]
        with pytest.raises(OSError, match=f"test-other: cannot listen on 127.0.0.1:{server.port}"):
            TCPServer("127.0.0.1", server.port, broken, name="test-other")
    finally:
        server.close()
