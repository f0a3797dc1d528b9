"""The simulated Elite EC controller is strict like the real one (real sockets, loopback)."""

from __future__ import annotations

import json
import math
import socket
import struct
import time

import numpy as np
import pytest

pytest.importorskip("mujoco")

from conftest import EC66_Q0, EC66_TIME_SCALE, tweak  # noqa: E402
from payload_agent.configuration.config import parse_config  # noqa: E402
from payload_agent.fakes.arms import ec66_spec  # noqa: E402
from payload_agent.fakes.base import FAULTS  # noqa: E402
from payload_agent.model.kinematics import Kinematics  # noqa: E402
from payload_agent.fakes.elite_ec import NOT_REMOTE_CODE, FakeEliteController  # noqa: E402
from payload_agent.fakes.elite_ec_monitor import FRAME_SIZE, MONITOR_LAYOUT, unpack_frame  # noqa: E402

Q0 = EC66_Q0
TIME_SCALE = EC66_TIME_SCALE


@pytest.fixture
def sim(ec66_sim):
    return ec66_sim


@pytest.fixture
def ctrl(sim):
    gain = [1.0, 1.03, 0.98, 1.0, 1.0, 1.0]
    c = FakeEliteController(sim, rpc_port=0, monitor_port=0, gain_error=gain)
    c.start()
    yield c
    c.close()


class Raw:
    """A bare 8055 client: bytes in, lines out."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=3.0)
        self.buf = b""

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def line(self, timeout: float = 3.0) -> bytes | None:
        self.sock.settimeout(timeout)
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            if time.monotonic() > deadline:
                return None
            try:
                chunk = self.sock.recv(4096)
            except socket.timeout:
                return None
            if not chunk:
                return None
            self.buf += chunk
        out, self.buf = self.buf.split(b"\n", 1)
        return out

    def call(self, method: str, params=None, req_id: int = 1) -> dict:
        req = {"jsonrpc": "2.0", "method": method, "params": params if params is not None else {}, "id": req_id}
        self.send((json.dumps(req) + "\n").encode())
        reply = self.line()
        assert reply is not None, f"no reply to {method}"
        return json.loads(reply)

    def result(self, method: str, params=None):
        reply = self.call(method, params)
        assert "result" in reply, reply
        assert isinstance(reply["result"], str), "result must be a JSON-encoded string"
        return json.loads(reply["result"])

    def close(self):
        self.sock.close()


@pytest.fixture
def raw(ctrl):
    r = Raw(ctrl.rpc_port)
    yield r
    r.close()


def wait_state(raw: Raw, wanted: int, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if raw.result("getRobotState") == wanted:
            return
        time.sleep(0.005)
    raise AssertionError(f"robotState never became {wanted}")


# -- JSON-RPC framing and envelope --------------------------------------------------------------

def test_results_are_json_encoded_strings(raw):
    assert raw.call("getRobotMode")["result"] == "2"
    assert raw.call("getServoStatus")["result"] == "true"
    reply = raw.call("get_joint_pos")
    assert reply["jsonrpc"] == "2.0" and reply["id"] == 1
    pos = json.loads(reply["result"])
    assert len(pos) == 8 and np.allclose(pos[:6], np.degrees(Q0))
    assert isinstance(raw.result("getSoftVersion"), str)
    assert raw.result("getRobotSubtype") == 6
    assert len(raw.result("getRobotTorques")) == 8
    assert len(raw.result("get_motor_torque")) == 8
    assert raw.result("get_estop_status") == 0
    assert raw.result("getRobotState") == 0


def test_request_without_newline_is_not_answered_until_newline(raw):
    raw.send(b'{"jsonrpc":"2.0","method":"getRobotMode","params":{},"id":7}')
    assert raw.line(timeout=0.3) is None
    raw.send(b"\n")
    reply = json.loads(raw.line())
    assert reply == {"jsonrpc": "2.0", "result": "2", "id": 7}


def test_request_split_over_many_chunks(raw):
    data = b'{"jsonrpc":"2.0","method":"getRobotSubtype","params":{},"id":11}\n'
    for i in range(0, len(data), 5):
        raw.send(data[i:i + 5])
        time.sleep(0.002)
    reply = json.loads(raw.line())
    assert reply["id"] == 11 and reply["result"] == "6"


def test_coalesced_requests_answered_in_order(raw):
    reqs = [{"jsonrpc": "2.0", "method": m, "params": {}, "id": i}
            for i, m in enumerate(["getRobotMode", "getRobotSubtype", "get_estop_status"], start=1)]
    raw.send(b"".join((json.dumps(r) + "\n").encode() for r in reqs))
    replies = [json.loads(raw.line()) for _ in reqs]
    assert [r["id"] for r in replies] == [1, 2, 3]
    assert [r["result"] for r in replies] == ["2", "6", "0"]


def test_error_codes(raw):
    assert raw.call("noSuchMethod")["error"]["code"] == -32601
    raw.send(b'{"jsonrpc":"2.0","method":"getRobotMode",,,}\n')
    err = json.loads(raw.line())
    assert err["error"]["code"] == -32700 and err["id"] is None
    raw.send(b'[1, 2]\n')
    assert json.loads(raw.line())["error"]["code"] == -32600
    bad = [
        ("moveByJoint", {"targetPos": [0, 0, 0, 0, 0], "speed": 10}),
        ("moveByJoint", {"targetPos": [0, -90, 90, 0, 90, 0], "speed": 0}),
        ("moveByJoint", {"targetPos": [0, -90, 90, 0, 90, 0], "speed": 101}),
        ("moveByJoint", {"targetPos": [0, -90, 90, 0, 90, "x"], "speed": 10}),
        ("moveByJoint", {"targetPos": [0, -90, 90, 0, 90, 0], "speed": 10, "acc": 150}),
        ("cmd_set_payload", {"tool_num": 9, "m": 1.0, "cog": [0, 0, 0]}),
        ("cmd_set_payload", {"tool_num": 0, "m": -1.0, "cog": [0, 0, 0]}),
        ("cmd_set_payload", {"tool_num": 0, "m": 1.0, "cog": [0, 0]}),
        ("get_tool_payload", {}),
        ("set_servo_status", {"status": 3}),
    ]
    for method, params in bad:
        reply = raw.call(method, params)
        assert reply.get("error", {}).get("code") == -32602, (method, params, reply)


def test_motion_and_settings_refused_outside_remote_mode(ctrl, raw, sim):
    for mode in (0, 1):
        ctrl.set_mode(mode)
        assert raw.result("getRobotMode") == mode
        for method, params in (("moveByJoint", {"targetPos": [10, -90, 90, 0, 90, 0], "speed": 20}),
                               ("cmd_set_payload", {"tool_num": 0, "m": 1.0, "cog": [0, 0, 50]}),
                               ("set_servo_status", {"status": 1})):
            reply = raw.call(method, params)
            assert "result" not in reply
            assert reply["error"]["code"] == NOT_REMOTE_CODE
            assert "remote" in reply["error"]["message"].lower()
        # queries still answer
        assert len(raw.result("get_joint_pos")) == 8
    time.sleep(0.05)
    assert np.allclose(sim.snapshot().q, Q0)
    assert ctrl.payload_setting(0)["m"] == 0.0


# -- motion -------------------------------------------------------------------------------------

def test_move_by_joint_returns_at_once_and_runs(raw, sim):
    target = [20.0, -80.0, 95.0, 5.0, 90.0, -10.0, 0.0, 0.0]
    t0 = sim.now()
    assert raw.result("moveByJoint", {"targetPos": target, "speed": 3, "acc": 50, "dec": 50}) is True
    assert raw.result("getRobotState") == 3  # running right after the reply
    assert sim.now() - t0 < 2.0  # answered long before the move (about 5 s of sim time) ends
    wait_state(raw, 0, timeout=10)
    assert np.allclose(raw.result("get_joint_pos")[:6], target[:6], atol=1e-6)
    # the speed percentage applies to each joint's maximum: J1 leads (20 deg at 3 % of its maximum)
    v_j1 = 0.03 * math.degrees(ec66_spec().max_speed_rad_s[0])
    assert 20.0 / v_j1 < sim.now() - t0 < 20.0 / v_j1 + 2.0


def test_six_value_target_accepted(raw):
    assert raw.result("moveByJoint", {"targetPos": [1.0, -90, 90, 0, 90, 0], "speed": 50}) is True
    wait_state(raw, 0)
    assert raw.result("get_joint_pos")[0] == pytest.approx(1.0)


def test_estop_stops_motion_and_needs_clear_and_servo(ctrl, raw, sim):
    assert raw.result("moveByJoint", {"targetPos": [60, -90, 90, 0, 90, 0], "speed": 5}) is True
    time.sleep(0.02)
    ctrl.press_estop()
    assert raw.result("getRobotState") == 2
    assert raw.result("get_estop_status") == 1
    assert raw.result("getServoStatus") is False
    assert raw.result("moveByJoint", {"targetPos": [0, -90, 90, 0, 90, 0], "speed": 5}) is False
    assert raw.result("clearAlarm") is False  # still pressed
    ctrl.release_estop()
    assert raw.result("getRobotState") == 4  # alarm remains
    assert raw.result("set_servo_status", {"status": 1}) is False
    assert raw.result("clearAlarm") is True
    assert raw.result("set_servo_status", {"status": 1}) is True
    wait_state(raw, 0)  # on the controller's next cycle (the simulated clock may lag on a loaded machine)
    assert raw.result("getServoStatus") is True
    assert raw.result("get_joint_pos")[0] < 60.0  # it never arrived


def test_collision_state(ctrl, raw):
    ctrl.trigger_collision()
    assert raw.result("getRobotState") == 5
    assert raw.result("getCollisionState") == 1
    assert raw.result("clearAlarm") is True
    assert raw.result("getRobotState") == 0


def test_payload_roundtrip_and_legacy_point(raw, ctrl):
    assert raw.result("cmd_set_payload", {"tool_num": 2, "m": 1.25, "cog": [10.0, -5.0, 60.0]}) is True
    assert raw.result("get_tool_payload", {"tool_num": 2}) == {"m": 1.25, "tool_cog": [10.0, -5.0, 60.0]}
    assert raw.result("cmd_set_payload", {"tool_num": 3, "m": 0.5, "point": [0, 0, 20]}) is True
    assert ctrl.payload_setting(3) == {"m": 0.5, "tool_cog": [0.0, 0.0, 20.0]}
    assert raw.result("getPayload", {"tool_num": 2}) == 1.25


def test_torque_percent_of_rated_with_gain_error(raw, ctrl, sim):
    pct = np.asarray(raw.result("getRobotTorques")[:6])
    tau = sim.snapshot().torque_nm
    expected = tau / np.asarray(ec66_spec().rated_torque_nm) * 100.0 * ctrl.gain_error
    assert np.allclose(pct, expected, atol=1e-9)
    assert abs(pct[1]) > 1.0  # joint 2 holds the arm against gravity


# -- monitor port -------------------------------------------------------------------------------

def read_frames(port: int, n: int, chunk_sizes=(4096,), timeout: float = 5.0) -> list[bytes]:
    sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    buf = b""
    frames: list[bytes] = []
    i = 0
    try:
        while len(frames) < n:
            data = sock.recv(chunk_sizes[i % len(chunk_sizes)])
            i += 1
            assert data, "monitor port closed"
            buf += data
            while len(buf) >= 4:
                size = struct.unpack_from("!I", buf)[0]
                if len(buf) < size:
                    break
                frames.append(buf[:size])
                buf = buf[size:]
    finally:
        sock.close()
    return frames


def test_monitor_layout_table_is_the_public_one():
    offsets = {name: off for name, off, _, _ in MONITOR_LAYOUT}
    assert offsets["MessageSize"] == 0 and offsets["TimeStamp"] == 4 and offsets["machinePos"] == 13
    assert offsets["torque"] == 173 and offsets["robotState"] == 237 and offsets["servoReady"] == 241
    assert offsets["robotMode"] == 281 and offsets["collision"] == 365 and offsets["emergencyStopState"] == 462
    assert offsets["joint_speed"] == 471 and offsets["jointTorque"] == 655
    assert FRAME_SIZE == 1024


def test_monitor_frames_layout_and_rate_in_sim_time(ctrl, sim):
    frames = read_frames(ctrl.monitor_port, 30)
    for f in frames:
        assert len(f) == 1024
        assert struct.unpack_from("!I", f, 0)[0] == 1024
    stamps = [struct.unpack_from("!Q", f, 4)[0] for f in frames]
    assert all(b - a == 8 for a, b in zip(stamps, stamps[1:])), stamps
    f = frames[-1]
    pos = struct.unpack_from("!8d", f, 13)
    assert np.allclose(pos[:6], np.degrees(Q0), atol=1e-9) and pos[6:] == (0.0, 0.0)
    torque = struct.unpack_from("!8d", f, 173)
    expected = sim.snapshot().torque_nm / np.asarray(ec66_spec().rated_torque_nm) * 100.0 * ctrl.gain_error
    assert np.allclose(torque[:6], expected, atol=1e-6)
    assert struct.unpack_from("!i", f, 237)[0] == 0  # robotState stop
    assert struct.unpack_from("!i", f, 241)[0] == 1  # servoReady
    assert struct.unpack_from("!i", f, 281)[0] == 2  # robotMode remote
    assert f[365] == 0 and f[462] == 0  # collision, e-stop
    joint_torque = struct.unpack_from("!6d", f, 655)
    assert np.allclose(joint_torque, sim.snapshot().torque_nm, atol=1e-9)
    decoded = unpack_frame(f)
    assert decoded["MessageSize"] == 1024 and decoded["robotMode"] == 2


def test_monitor_reports_motion_and_estop(ctrl, raw):
    assert raw.result("moveByJoint", {"targetPos": [30, -90, 90, 0, 90, 0], "speed": 2}) is True  # 10 s of sim time
    frames = read_frames(ctrl.monitor_port, 5)
    d = unpack_frame(frames[-1])
    assert d["robotState"] == 3 and d["joint_speed"][0] > 0.0
    ctrl.press_estop()
    time.sleep(0.02)
    d = unpack_frame(read_frames(ctrl.monitor_port, 2)[-1])
    assert d["robotState"] == 2 and d["emergencyStopState"] == 1 and d["servoReady"] == 0


def test_monitor_odd_size_chunks_still_frame(ctrl):
    frames = read_frames(ctrl.monitor_port, 20, chunk_sizes=(7, 333, 1, 1500, 64, 1023))
    stamps = [unpack_frame(f)["TimeStamp"] for f in frames]
    assert all(len(f) == 1024 for f in frames)
    assert all(b - a == 8 for a, b in zip(stamps, stamps[1:]))


def test_slow_monitor_client_is_dropped_without_stalling_sim(sim):
    with FakeEliteController(sim, rpc_port=0, monitor_port=0) as c:
        c._monitor.max_queue = 10
        lazy = socket.socket()
        lazy.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        lazy.connect(("127.0.0.1", c.monitor_port))
        t0 = sim.now()
        deadline = time.monotonic() + 15
        while c._monitor.dropped_clients == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert c._monitor.dropped_clients == 1
        assert sim.now() > t0  # the clock kept running
        c._monitor.max_queue = 1000
        # a well-behaved client still gets frames
        assert len(read_frames(c.monitor_port, 3)) >= 3
        lazy.close()


# -- the simulated-controller contract ------------------------------------------------------------

def test_host_auto_serves_the_real_ports_on_a_free_loopback_address(sim_ec66_data):
    """sim-ec66.yaml's `host: auto`: 8055/8056 as on the robot, on a 127.0.0.x no other simulation holds, so two
    simulated EC66 from the same YAML (two test workers, a benchmark beside the suite) run at once."""
    cfg = parse_config(sim_ec66_data, source="test")
    assert cfg.driver_options.host == "auto"
    first = FakeEliteController.from_config(cfg).start()
    try:
        second = FakeEliteController.from_config(cfg).start()
        try:
            assert (first.rpc_port, first.monitor_port) == (second.rpc_port, second.monitor_port) == (8055, 8056)
            assert first.host != second.host and all(h.startswith("127.0.0.") for h in (first.host, second.host))
            assert second.bound_options(cfg.driver_options).host == second.host
        finally:
            second.close()
    finally:
        first.close()


def test_from_config_builds_robot_and_binds_ephemeral_ports(sim_ec66_data):
    data = tweak(tweak(sim_ec66_data, "driver.rpc_port", 0), "driver.monitor_port", 0)
    data = tweak(data, "driver.host", "127.0.0.1")
    data = tweak(data, "simulation.drive_gain_error", [1.0, 1.04, 0.97, 1.0, 1.0, 1.0])
    cfg = parse_config(data, source="test")
    c = FakeEliteController.from_config(cfg)
    try:
        c.start()
        opts = c.bound_options(cfg.driver_options)
        assert opts.host == "127.0.0.1" and opts.rpc_port == c.rpc_port > 0 and opts.monitor_port == c.monitor_port > 0
        assert opts.sample_source == cfg.driver_options.sample_source  # everything else kept
        assert c.robot.tick_s == 0.008 and c.robot.time_scale == cfg.simulation.time_scale
        assert np.allclose(c.robot.snapshot().q, np.radians(cfg.simulation.start_deg), atol=1e-4)  # angle noise
        assert np.allclose(c.rated_torque_nm, ec66_spec().rated_torque_nm)
        assert c.gain_error[1] == pytest.approx(1.04) and c.gain_error[2] == pytest.approx(0.97)
        t0 = c.robot.now()
        deadline = time.monotonic() + 2.0
        while c.robot.now() == t0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert c.robot.now() > t0  # start() started the robot it built
        raw = Raw(opts.rpc_port)
        assert raw.result("getRobotSubtype") == 6
        raw.close()
        assert c.payload is None
    finally:
        c.close()


def test_events_log_every_accepted_move_and_every_stop(ctrl, raw):
    t0 = time.monotonic()
    assert raw.result("moveByJoint", {"targetPos": [60, -90, 90, 0, 90, 0], "speed": 1}) is True  # ~1 s of wall time
    assert raw.result("moveByJoint", {"targetPos": [9, -90, 90, 0, 90, 0], "speed": 50}) is False  # still running
    assert raw.result("stop") is True
    ctrl.set_mode(0)
    raw.call("moveByJoint", {"targetPos": [0, -90, 90, 0, 90, 0], "speed": 50})  # refused: not remote
    kinds = [e.kind for e in ctrl.events if e.t >= t0]
    assert kinds == ["move", "stop"]
    assert "targetPos" in ctrl.events[0].detail


def test_unknown_fault_is_refused(ctrl):
    assert ctrl.faults == frozenset(FAULTS)
    with pytest.raises(ValueError, match="unknown fault"):
        ctrl.inject_fault("meteor_strike")


# -- Cartesian poses: the simulated arm's own kinematics, Elite units -------------------------------

def rpy_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """Elite's pose rotation, R = Rz(rz)·Ry(ry)·Rx(rx) (docs/sources.md), built independently here."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def assert_pose_is_fk(pose, q, angles_in_deg=False):
    fk = Kinematics(ec66_spec().dh).flange(q)
    assert np.allclose(pose[:3], fk[:3, 3] * 1000.0, atol=1e-6)  # mm
    angles = np.radians(pose[3:]) if angles_in_deg else np.asarray(pose[3:])
    assert np.allclose(rpy_matrix(*angles), fk[:3, :3], atol=1e-9)


def test_poses_from_rpc_are_the_arms_forward_kinematics(raw, sim):
    target = [20.0, -70.0, 100.0, 30.0, 60.0, -45.0]
    assert raw.result("moveByJoint", {"targetPos": target, "speed": 100}) is True
    wait_state(raw, 0)
    q = sim.snapshot().q
    assert np.allclose(np.degrees(q), target, atol=1e-6)
    assert_pose_is_fk(raw.result("get_base_flange_pose"), q)
    assert_pose_is_fk(raw.result("get_base_flange_pose", {"unit_type": 1}), q)
    assert_pose_is_fk(raw.result("get_base_flange_pose", {"unit_type": 0}), q, angles_in_deg=True)
    assert_pose_is_fk(raw.result("get_tcp_pose", {"coordinate_num": -1, "tool_num": 0}), q)
    assert raw.call("get_tcp_pose", {"tool_num": 9})["error"]["code"] == -32602
    assert raw.call("get_base_flange_pose", {"unit_type": 2})["error"]["code"] == -32602


def test_monitor_poses_are_the_arms_forward_kinematics(ctrl, sim):
    f = unpack_frame(read_frames(ctrl.monitor_port, 3)[-1])
    q = np.radians(f["machinePos"][:6])
    for field in ("machineFlangePose", "machinePose", "machineUserFlangePose", "machineUserPose"):
        assert_pose_is_fk(f[field], q)


# -- faults at the protocol level -----------------------------------------------------------------

def test_stall_stream_stops_frames_and_clearing_resumes_them(ctrl):
    sock = socket.create_connection(("127.0.0.1", ctrl.monitor_port), timeout=2.0)
    try:
        assert sock.recv(4096)
        ctrl.inject_fault("stall_stream")
        time.sleep(0.05)
        sock.settimeout(0.05)
        try:  # drain what was sent before the stall
            while sock.recv(65536):
                pass
        except socket.timeout:
            pass
        sent = ctrl.frames_sent
        sock.settimeout(0.3)
        with pytest.raises(socket.timeout):
            sock.recv(4096)
        assert ctrl.frames_sent == sent
        ctrl.clear_faults()
        sock.settimeout(2.0)
        assert sock.recv(4096)  # the same connection gets frames again
    finally:
        sock.close()


def test_garbage_and_nan_faults_on_the_monitor(ctrl):
    ctrl.inject_fault("nan_values")
    f = unpack_frame(read_frames(ctrl.monitor_port, 2)[-1])
    assert math.isnan(f["machinePos"][1]) and math.isnan(f["torque"][1])
    ctrl.clear_faults()
    ctrl.inject_fault("garbage")
    sock = socket.create_connection(("127.0.0.1", ctrl.monitor_port), timeout=2.0)
    try:
        data = b""
        while len(data) < 8:
            data += sock.recv(4096)
    finally:
        sock.close()
    size = struct.unpack_from("!I", data)[0]
    assert size != FRAME_SIZE and size > 1 << 16  # no Elite frame announces that


def test_drop_connections_closes_clients_but_serves_new_ones(ctrl, raw):
    mon = socket.create_connection(("127.0.0.1", ctrl.monitor_port), timeout=2.0)
    try:
        assert raw.result("getRobotMode") == 2
        ctrl.inject_fault("drop_connections")
        assert raw.line(timeout=1.0) is None  # EOF
        deadline = time.monotonic() + 2.0
        while mon.recv(65536) and time.monotonic() < deadline:
            pass  # frames queued before the drop, then EOF
        fresh = Raw(ctrl.rpc_port)
        assert fresh.result("getRobotMode") == 2
        fresh.close()
        assert len(read_frames(ctrl.monitor_port, 2)) >= 2
    finally:
        mon.close()


def test_slow_reply_executes_at_once_and_answers_late(ctrl, raw, sim):
    ctrl.inject_fault("slow_reply", delay_s=0.4)
    t0 = time.monotonic()
    raw.send(b'{"jsonrpc":"2.0","method":"moveByJoint","params":{"targetPos":[8,-90,90,0,90,0],"speed":50},"id":3}\n')
    deadline = time.monotonic() + 2.0
    while ctrl.first_event_after("move", t0) is None and time.monotonic() < deadline:
        time.sleep(0.005)
    move = ctrl.first_event_after("move", t0)
    assert move is not None and move.t - t0 < 0.3
    reply = raw.line(timeout=2.0)
    assert json.loads(reply)["result"] == "true" and time.monotonic() - t0 >= 0.4
    ctrl.clear_faults()
    t1 = time.monotonic()
    assert raw.result("getRobotMode") == 2 and time.monotonic() - t1 < 0.3


def test_no_reply_hangs_the_open_sessions_but_serves_a_new_one(ctrl, raw):
    assert raw.result("getRobotMode") == 2  # the session is being served
    ctrl.inject_fault("no_reply")
    raw.send(b'{"jsonrpc":"2.0","method":"stop","params":{},"id":4}\n')
    assert raw.line(timeout=0.4) is None
    assert not [e for e in ctrl.events if e.kind == "stop"]  # swallowed: not executed either
    fresh = Raw(ctrl.rpc_port)
    assert fresh.result("stop") is True
    fresh.close()
    assert [e.kind for e in ctrl.events] == ["stop"]
    ctrl.clear_faults()
    assert raw.result("getRobotMode") == 2


def test_never_finish_keeps_running_until_stopped(ctrl, raw, sim):
    ctrl.inject_fault("never_finish")
    assert raw.result("moveByJoint", {"targetPos": [3, -90, 90, 0, 90, 0], "speed": 100}) is True
    deadline = time.monotonic() + 5.0
    while sim.snapshot().moving or abs(math.degrees(sim.snapshot().q[0]) - 3.0) > 1e-6:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    time.sleep(0.05)
    assert raw.result("getRobotState") == 3  # arrived, and still "running"
    assert raw.result("stop") is True
    wait_state(raw, 0)


@pytest.mark.parametrize("fault,state,mode", [("protective_stop", 5, 2), ("emergency_stop", 2, 2),
                                              ("leave_remote", 0, 0)])
def test_safety_and_mode_faults(ctrl, raw, fault, state, mode):
    ctrl.inject_fault(fault)
    assert raw.result("getRobotState") == state and raw.result("getRobotMode") == mode
