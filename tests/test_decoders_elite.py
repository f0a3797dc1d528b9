"""Property-based tests of the Elite EC driver's wire decoders (issue 13, "bad input").

What the controller sends reaches the driver over real loopback sockets:

* JSON-RPC reply lines (port 8055, ``rpc.RpcClient``): arbitrary bytes, and well-formed
  envelopes around arbitrary JSON, give a decoded result or ``CommunicationError`` (an
  ``EliteRPCError`` for an error object), never another exception, never a hang;
* the driver's readers of those results (``state``, ``identify``, ``read_payload``,
  ``flange_pose``, ``read_digital_input``, the poll-mode sample): a value or CommunicationError
  for any JSON the controller may answer (NaN, Infinity, huge integers, wrong shapes);
* monitor frames (port 8056, ``monitor.MonitorStream``): an arbitrary byte stream gives frames
  or CommunicationError; the fake's encoder (``fakes.elite_ec_monitor.pack_frame``) and the
  driver's decoder agree field by field however the stream is cut into TCP chunks.

Every call that waits on a socket runs under ``bounded``: a hang fails the test instead of
stalling the suite. Hypothesis runs without deadlines (a loaded CI machine must not flake);
the work per example is bounded instead.
"""

from __future__ import annotations

import json
import math
import os
import socket
import struct
import threading

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from payload_agent.drivers.base import MotionLimits
from payload_agent.drivers.elite_ec import monitor as mon
from payload_agent.drivers.elite_ec.driver import EliteECDriver
from payload_agent.drivers.elite_ec.options import EliteECOptions
from payload_agent.drivers.elite_ec.rpc import EliteRPCError, RpcClient
from payload_agent.errors import CommunicationError
from payload_agent.fakes.elite_ec_monitor import FRAME_SIZE, MONITOR_LAYOUT, pack_frame
from payload_agent.types import ControllerInfo, ControllerState, FlangePose, PayloadSetting, Sample
from fuzzing import HANG_S, bounded  # noqa: F401

# DECODER_FUZZ_SCALE=20 searches 20 times harder (a deep run by hand; the suite keeps the default)
SCALE = float(os.environ.get("DECODER_FUZZ_SCALE", "1"))
FUZZ = settings(max_examples=int(80 * SCALE), deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
REPLY_TIMEOUT_S = 0.5




class ReplyServer:
    """A loopback JSON-RPC "controller": each connection reads request lines and answers each with
    ``answer(request_dict) -> bytes``; ``close_after`` requests it closes the connection."""

    def __init__(self):
        self._ls = socket.create_server(("127.0.0.1", 0))
        self._ls.settimeout(0.2)
        self.port = self._ls.getsockname()[1]
        self.answer = lambda req: b""
        self.close_after = 1
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self):
        while not self._stop.is_set():
            try:
                conn, _ = self._ls.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn):
        answer, close_after = self.answer, self.close_after
        conn.settimeout(HANG_S)
        buf = b""
        served = 0
        try:
            while served < close_after:
                while b"\n" not in buf:
                    chunk = conn.recv(65536)
                    if not chunk:
                        return
                    buf += chunk
                line, buf = buf.split(b"\n", 1)
                conn.sendall(answer(json.loads(line)))
                served += 1
        except OSError:
            pass
        finally:
            conn.close()

    def client(self) -> RpcClient:
        return RpcClient("127.0.0.1", self.port, 2.0, REPLY_TIMEOUT_S)

    def close(self):
        self._stop.set()
        self._ls.close()


@pytest.fixture(scope="module")
def server():
    srv = ReplyServer()
    yield srv
    srv.close()


# -- JSON values as a controller might send them: NaN, infinities, huge integers, deep nesting ----------
json_scalars = (st.none() | st.booleans() | st.integers() | st.integers(min_value=10 ** 300, max_value=10 ** 320)
                | st.floats() | st.text(max_size=12))
json_values = st.recursive(json_scalars, lambda kids: st.lists(kids, max_size=8)
                           | st.dictionaries(st.text(max_size=6), kids, max_size=5), max_leaves=20)
deep = st.integers(min_value=1, max_value=5000).map(lambda n: "[" * n + "]" * n)


def envelope(req_id, **fields) -> bytes:
    return json.dumps({"jsonrpc": "2.0", **fields, "id": req_id}).encode() + b"\n"


reply_builders = st.one_of(
    # arbitrary bytes: with or without a newline, the server closes after them
    st.binary(max_size=300).map(lambda b: (lambda req: b)),
    st.binary(max_size=300).map(lambda b: (lambda req: b + b"\n")),
    # a result: double-encoded (the Elite way), raw, or a string that is not JSON
    json_values.map(lambda v: (lambda req: envelope(req["id"], result=json.dumps(v)))),
    json_values.map(lambda v: (lambda req: envelope(req["id"], result=v))),
    deep.map(lambda s: (lambda req: envelope(req["id"], result=s))),
    deep.map(lambda s: (lambda req: s.encode() + b"\n")),
    # an error object of any shape, and envelopes missing parts or answering another id
    json_values.map(lambda v: (lambda req: envelope(req["id"], error=v))),
    st.fixed_dictionaries({"code": json_values, "message": json_values}).map(
        lambda e: (lambda req: envelope(req["id"], error=e))),
    json_values.map(lambda v: (lambda req: envelope(v, result="1"))),
    st.just(lambda req: envelope(req["id"])),
)


@FUZZ
@given(reply_builders)
def test_rpc_reply_is_a_result_or_a_communication_error(server, answer):
    server.answer, server.close_after = answer, 1
    client = server.client()
    try:
        try:
            bounded(client.call, "getRobotMode")
        except EliteRPCError as exc:
            assert isinstance(exc.code, int) and isinstance(exc.rpc_message, str)
        except CommunicationError:
            pass
    finally:
        client.close()


# -- the driver's readers of decoded results -------------------------------------------------------------
def elite_driver(port: int, sample_source: str = "poll") -> EliteECDriver:
    opts = EliteECOptions(type="elite_ec", host="127.0.0.1", rpc_port=port, monitor_port=port,
                          sample_source=sample_source, reply_timeout_s=REPLY_TIMEOUT_S, connect_timeout_s=2.0)
    return EliteECDriver(opts, MotionLimits(math.radians(180), math.radians(360)))


def _readers(drv: EliteECDriver):
    return [("state", drv.state, ControllerState), ("identify", drv.identify, ControllerInfo),
            ("read_payload", drv.read_payload, PayloadSetting), ("flange_pose", drv.flange_pose, FlangePose),
            ("read_digital_input", lambda: drv.read_digital_input(3), bool),
            ("poll sample", lambda: drv._poll_sample(1.0), Sample)]


# a controller whose every reply carries one arbitrary (double-encoded) result, or one per method
per_method = st.dictionaries(st.sampled_from(["getRobotMode", "getServoStatus", "get_estop_status", "getRobotState",
                                              "getSoftVersion", "getRobotSubtype", "get_tool_payload",
                                              "get_base_flange_pose", "getInput", "get_joint_pos",
                                              "getRobotTorques"]), json_values, max_size=11)
numbers_like = st.lists(st.floats() | st.integers(min_value=-10 ** 320, max_value=10 ** 320), min_size=5, max_size=9)


@FUZZ
@given(st.one_of(json_values.map(lambda v: {None: v}), per_method,
                 numbers_like.map(lambda v: {"get_base_flange_pose": v, "get_joint_pos": v, "getRobotTorques": v}),
                 st.fixed_dictionaries({"m": json_values | st.floats(), "tool_cog": numbers_like | json_values}).map(
                     lambda v: {"get_tool_payload": v})),
       st.sampled_from(range(6)))
def test_driver_reads_any_result_as_a_value_or_a_communication_error(server, results, which):
    def answer(req):
        value = results.get(req["method"], results.get(None, 0))
        return envelope(req["id"], result=json.dumps(value))

    server.answer, server.close_after = answer, 10 ** 6
    drv = elite_driver(server.port)
    drv._rpc = server.client()
    drv._poll_rpc = server.client()
    try:
        name, reader, kind = _readers(drv)[which]
        try:
            value = bounded(reader)
        except CommunicationError:
            return
        assert isinstance(value, kind), f"{name} returned {value!r}"
        if isinstance(value, FlangePose):
            assert all(math.isfinite(v) for v in value.position_m)
            assert all(math.isfinite(v) for row in value.rotation for v in row)
        if isinstance(value, PayloadSetting):
            assert math.isfinite(value.mass_kg) and all(math.isfinite(c) for c in value.cog_m)
    finally:
        drv._rpc.close()
        drv._poll_rpc.close()


# -- monitor frames ----------------------------------------------------------------------------------------
class StreamSource:
    """A loopback monitor port that sends ``chunks`` (one sendall each) and then closes."""

    def __init__(self, chunks: list[bytes]):
        ls = socket.create_server(("127.0.0.1", 0))
        self.port = ls.getsockname()[1]
        self._ls = ls
        self._chunks = chunks
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        self._ls.settimeout(HANG_S)
        try:
            conn, _ = self._ls.accept()
        except OSError:
            return
        finally:
            self._ls.close()
        with conn:
            try:
                for c in self._chunks:
                    conn.sendall(c)
            except OSError:
                pass


def read_all(stream: mon.MonitorStream) -> tuple[list[mon.MonitorFrame], CommunicationError | None]:
    """Read until the stream ends; every read returns frames or raises CommunicationError."""
    frames: list[mon.MonitorFrame] = []
    for _ in range(10_000):  # each read consumes at least one byte or ends the stream
        try:
            got = stream.read(REPLY_TIMEOUT_S)
        except CommunicationError as exc:
            return frames, exc
        assert isinstance(got, list) and all(isinstance(f, mon.MonitorFrame) for f in got)
        frames.extend(got)
    pytest.fail("the monitor stream never ended")


def monitor_frames(chunks: list[bytes]):
    src = StreamSource(chunks)
    stream = mon.MonitorStream("127.0.0.1", src.port, 2.0)
    try:
        return bounded(read_all, stream)
    finally:
        stream.close()


def sized_frame(size: int, body: bytes) -> bytes:
    return struct.pack("!I", size) + (body * (size // max(len(body), 1) + 1))[:max(size - 4, 0)]


monitor_streams = st.one_of(
    st.lists(st.binary(max_size=1500), max_size=4),
    st.lists(st.builds(sized_frame, st.integers(0, 5000), st.binary(min_size=1, max_size=64)), max_size=4),
    st.lists(st.builds(sized_frame, st.integers(mon.MIN_SIZE, 2000), st.binary(min_size=1, max_size=64)),
             max_size=4),
)


@FUZZ
@given(monitor_streams)
def test_monitor_stream_gives_frames_or_a_communication_error(chunks):
    frames, end = monitor_frames(chunks)
    assert end is not None  # the port closed: the stream says so
    for f in frames:
        assert len(f.joint_deg) == 8 and len(f.torque_pct) == 8 and len(f.flange_pose) == 6


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
field_values = st.fixed_dictionaries({
    "TimeStamp": st.integers(0, 2 ** 64 - 1),
    "machinePos": st.lists(finite, min_size=8, max_size=8),
    "torque": st.lists(finite, min_size=8, max_size=8),
    "robotState": st.integers(-2 ** 31, 2 ** 31 - 1),
    "servoReady": st.integers(-2 ** 31, 2 ** 31 - 1),
    "robotMode": st.integers(-2 ** 31, 2 ** 31 - 1),
    "collision": st.integers(0, 255),
    "machineFlangePose": st.lists(finite, min_size=6, max_size=6),
    "emergencyStopState": st.integers(0, 255),
    "joint_temperature": st.lists(finite, min_size=6, max_size=6),
})


@settings(FUZZ, max_examples=int(50 * SCALE))  # a connection and a thread each: the costly kind under load
@given(st.lists(field_values, min_size=1, max_size=3), st.lists(st.integers(1, 3 * FRAME_SIZE), max_size=6))
def test_fake_frames_decode_to_the_same_fields_however_the_stream_is_cut(values, cuts):
    data = b"".join(pack_frame(v) for v in values)
    bounds = sorted({c for c in cuts if c < len(data)})
    chunks = [data[a:b] for a, b in zip([0, *bounds], [*bounds, len(data)])]
    frames, _ = monitor_frames(chunks)
    assert len(frames) == len(values)
    for f, v in zip(frames, values):
        assert f.timestamp_ms == v["TimeStamp"]
        assert list(f.joint_deg) == v["machinePos"] and list(f.torque_pct) == v["torque"]
        assert (f.robot_state, f.servo_ready, f.robot_mode) == (v["robotState"], v["servoReady"], v["robotMode"])
        assert (f.collision, f.estop) == (v["collision"], v["emergencyStopState"])
        assert list(f.flange_pose) == v["machineFlangePose"]
        assert list(f.joint_temperature) == v["joint_temperature"]


def test_driver_and_fake_agree_on_the_monitor_layout():
    """The driver's offsets are written out apart from the fake's table; they must name the same bytes."""
    layout = {name: off for name, off, _, _ in MONITOR_LAYOUT}
    assert mon._TIMESTAMP[0] == layout["TimeStamp"] and mon._MACHINE_POS[0] == layout["machinePos"]
    assert mon._TORQUE[0] == layout["torque"] and mon._ROBOT_STATE[0] == layout["robotState"]
    assert mon._FLANGE_POSE[0] == layout["machineFlangePose"] and mon._ESTOP[0] == layout["emergencyStopState"]
    assert mon._JOINT_TEMP[0] == layout["joint_temperature"]


SPECIAL = [math.nan, math.inf, -math.inf, 10 ** 400, -(10 ** 400), 2 ** 63, 1.5, -1, True, "", "7", None, [], {},
           [math.nan] * 8, [math.inf] * 8, [10 ** 400] * 8, [1e308] * 8, {"m": math.inf, "tool_cog": [0, 0, 0]},
           {"m": 10 ** 400, "tool_cog": [0, 0, 0]}, {"m": 1.0, "tool_cog": "abc"},
           {"m": 1.0, "tool_cog": [math.nan] * 3}]


@pytest.mark.parametrize("value", SPECIAL, ids=[repr(v)[:24] for v in SPECIAL])
def test_driver_reads_special_numbers_as_a_value_or_a_communication_error(server, value):
    """Every reader against one result for every method: the numbers JSON allows that Python's float does not."""
    server.answer = lambda req: envelope(req["id"], result=json.dumps(value))
    server.close_after = 10 ** 6
    drv = elite_driver(server.port)
    drv._rpc, drv._poll_rpc = server.client(), server.client()
    try:
        for name, reader, kind in _readers(drv):
            try:
                got = bounded(reader)
            except CommunicationError:
                continue
            assert isinstance(got, kind), f"{name} returned {got!r}"
    finally:
        drv._rpc.close()
        drv._poll_rpc.close()


any_double = st.floats(width=64)
frame_values = st.fixed_dictionaries({
    "TimeStamp": st.integers(0, 2 ** 64 - 1),
    "machinePos": st.lists(any_double, min_size=8, max_size=8),
    "torque": st.lists(any_double, min_size=8, max_size=8),
    "machineFlangePose": st.lists(any_double, min_size=6, max_size=6),
    "joint_temperature": st.lists(any_double, min_size=6, max_size=6),
    "robotState": st.integers(-2 ** 31, 2 ** 31 - 1),
})


@FUZZ
@given(st.lists(frame_values, min_size=1, max_size=3))
def test_driver_turns_any_monitor_frame_into_a_sample_or_a_communication_error(server, values):
    """The monitor path of the driver: samples (checked as the base's reader checks them), the flange
    pose and the joint temperatures from frames carrying any doubles, NaN and infinities included."""
    from payload_agent.drivers.stream import check_sample as _check_sample

    src = StreamSource([pack_frame(v) for v in values])
    drv = elite_driver(server.port, sample_source="monitor")
    server.close_after = 10 ** 6
    drv._rpc = server.client()  # connected, never called on the monitor path
    drv._monitor = mon.MonitorStream("127.0.0.1", src.port, 2.0)

    def drain():
        for _ in range(100):
            try:
                sample = drv._read_sample(REPLY_TIMEOUT_S)
            except CommunicationError:
                return
            if sample is None:
                continue
            try:
                _check_sample(sample, 6)
            except CommunicationError:
                pass
            else:
                assert all(math.isfinite(v) for v in sample.q + sample.effort)
            try:
                pose = drv.flange_pose()
            except CommunicationError:
                pass
            else:
                assert all(math.isfinite(v) for v in pose.position_m)
                assert all(math.isfinite(v) for row in pose.rotation for v in row)
            temps = drv.joint_temperatures_c()
            assert temps is None or (len(temps) == 6 and all(math.isfinite(t) for t in temps))
        pytest.fail("the monitor stream never ended")

    try:
        bounded(drain)
    finally:
        drv._monitor.close()
        drv._rpc.close()
