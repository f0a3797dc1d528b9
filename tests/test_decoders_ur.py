"""Property-based tests of the UR side's RTDE decoding (issue 13, "bad input").

The UR driver reads RTDE through ur-rtde's C++ client, whose package parser is not ours; what the
driver decodes itself is what ur-rtde hands it: the sample (timestamp, actual_q, actual_current)
and its plausibility check, the safety and mode words, the joint temperatures, the payload
readback, and actual_TCP_pose with getTCPOffset for the flange pose. Those are fuzzed here with
a receive interface that returns arbitrary doubles and integers (NaN, infinities, wrong lengths,
time running backwards): each reader gives a value (finite where it is a measurement) or
CommunicationError, never another exception.

The simulated controller's RTDE server (``fakes.ur.rtde_session``) parses client packages; it is
fed arbitrary bytes and arbitrary sequences of plausible packages over a socketpair and must
answer in well-framed RTDE (a protocol error as a text message or a refusal), never crash and
never hang.
"""

from __future__ import annotations

import math
import os
import socket
import struct
import threading

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from payload_agent.drivers.base import MotionLimits
from payload_agent.drivers.stream import check_sample as _check_sample
from payload_agent.drivers.ur_rtde.driver import URRTDEDriver
from payload_agent.drivers.ur_rtde.options import URRTDEOptions
from payload_agent.drivers.ur_rtde.states import (KNOWN_SAFETY_BITS, RUNTIME_NAMES, URStatus, controller_state,
                                                  safety_stop)
from payload_agent.errors import CommunicationError
from payload_agent.fakes import ur_rtde_protocol as rp
from payload_agent.types import ControllerState, FlangePose, PayloadSetting, Sample
from fuzzing import HANG_S, bounded  # noqa: F401

# DECODER_FUZZ_SCALE=20 searches 20 times harder (a deep run by hand; the suite keeps the default)
SCALE = float(os.environ.get("DECODER_FUZZ_SCALE", "1"))
FUZZ = settings(max_examples=int(150 * SCALE), deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])




# -- the driver's side ------------------------------------------------------------------------------------
class Package:
    """What ur-rtde's RTDEReceiveInterface returns from its latest package (the getters the driver calls)."""

    def __init__(self, ts, q, cur, qd=(0.0,) * 6, modes=(7, 1, 0, 2), temps=(30.0,) * 6, payload=(0.0, (0, 0, 0)),
                 tcp=(0.0,) * 6, targets=((0.0,) * 6, (0.0,) * 6)):
        self.ts, self.q, self.cur, self.qd, self.modes, self.temps = ts, list(q), list(cur), list(qd), modes, temps
        self.payload, self.tcp = payload, tcp
        self.target_current, self.target_moment = list(targets[0]), list(targets[1])

    def isConnected(self):
        return True

    def getTimestamp(self):
        return self.ts

    def getActualQ(self):
        return self.q

    def getActualCurrent(self):
        return self.cur

    def getActualQd(self):
        return self.qd

    def getTargetCurrent(self):
        return self.target_current

    def getTargetMoment(self):
        return self.target_moment

    def getRobotMode(self):
        return self.modes[0]

    def getSafetyMode(self):
        return self.modes[1]

    def getSafetyStatusBits(self):
        return self.modes[2]

    def getRuntimeState(self):
        return self.modes[3]

    def getJointTemperatures(self):
        return list(self.temps)

    def getPayload(self):
        return self.payload[0]

    def getPayloadCog(self):
        return list(self.payload[1])

    def getActualTCPPose(self):
        return list(self.tcp)

    def getDigitalInState(self, index):
        return bool(self.modes[2] >> index & 1)


class Control:
    """The command channel's answer to getTCPOffset."""

    def __init__(self, offset):
        self.lock = threading.Lock()
        self.offset = offset

    def request(self, op, *args, **kw):
        assert op == "getTCPOffset"
        return self.offset


def ur_driver() -> URRTDEDriver:
    drv = URRTDEDriver(URRTDEOptions(type="ur_rtde", host="127.0.0.1", frequency_hz=500.0),
                       MotionLimits(math.radians(180), math.radians(360)))
    drv._has_payload_fields = True
    drv._version = (5,)  # an e-Series without "is in remote control" (< 5.6): state() asks no dashboard
    return drv


doubles = st.floats(width=64)
plausible = st.floats(-6.0, 6.0)
ints = st.integers(-2 ** 31, 2 ** 32 - 1)
six = st.lists(doubles, min_size=6, max_size=6)
any_len = st.lists(doubles, max_size=8)
packages = st.builds(
    Package,
    ts=doubles | st.floats(0, 1e6),
    q=st.one_of(six, any_len, st.lists(plausible, min_size=6, max_size=6)),
    cur=st.one_of(six, any_len, st.lists(plausible, min_size=6, max_size=6)),
    qd=six, modes=st.tuples(ints, ints, ints, ints), temps=any_len,
    payload=st.tuples(doubles, st.lists(doubles, min_size=3, max_size=3)),
    tcp=st.one_of(six, any_len),
    targets=st.tuples(st.one_of(six, any_len), st.one_of(six, any_len)))


@FUZZ
@given(st.lists(packages, min_size=1, max_size=6))
@example([Package(1.0, [0.0] * 6, [0.0] * 6), Package(math.nan, [0.0] * 6, [0.0] * 6)])
@example([Package(1.0, [0.0] * 6, [0.0] * 6), Package(math.inf, [0.0] * 6, [0.0] * 6)])
@example([Package(-1.7e308, [0.0] * 6, [0.0] * 6), Package(1.7e308, [0.0] * 6, [0.0] * 6)])
def test_samples_are_finite_or_a_communication_error(pkgs):
    """_read_sample as the base's reader uses it (then _check_sample): a finite Sample, None, or the error."""
    drv = ur_driver()
    for pkg in pkgs:
        drv._recv = pkg
        try:
            sample = drv._read_sample(0.002)
            if sample is not None:
                _check_sample(sample, 6)
        except CommunicationError:
            return  # the stream ends here, as in the base's reader
        if sample is not None:
            assert isinstance(sample, Sample)
            assert all(math.isfinite(v) for v in (sample.t_ctrl, *sample.q, *sample.effort,
                                                   *sample.target_current, *sample.target_moment))
            assert drv.samples_missed >= 0


@FUZZ
@given(packages)
# finite but absurd: the pose and the TCP offset (its reverse) made "invalid value encountered in matmul"
@example(Package(1.0, [0.0] * 6, [0.0] * 6, tcp=[3.0, -1.0, 0.0, 1e308, 1.7e308, 1.0]))
@pytest.mark.filterwarnings("error::RuntimeWarning")  # absurd numbers are refused, never computed with
def test_state_temperatures_payload_and_pose_are_values_or_a_communication_error(pkg):
    drv = ur_driver()
    drv._recv = pkg
    drv._ensure_control = lambda: None
    drv._control = Control(pkg.tcp[::-1])
    for name, reader, kind in (("state", drv.state, ControllerState),
                               ("read_payload", drv.read_payload, PayloadSetting),
                               ("joint_temperatures_c", drv.joint_temperatures_c, tuple),
                               ("flange_pose", drv.flange_pose, FlangePose),
                               ("read_digital_input", lambda: drv.read_digital_input(3), bool)):
        try:
            value = reader()
        except CommunicationError:
            continue
        assert isinstance(value, kind), f"{name} returned {value!r}"
        if isinstance(value, PayloadSetting):
            assert math.isfinite(value.mass_kg) and all(math.isfinite(c) for c in value.cog_m)
        elif isinstance(value, FlangePose):
            assert all(math.isfinite(v) for v in value.position_m)
            assert all(math.isfinite(v) for row in value.rotation for v in row)
        elif name == "joint_temperatures_c":
            assert len(value) == 6 and all(math.isfinite(t) for t in value)


@FUZZ
@given(ints, ints, st.integers(-2 ** 63, 2 ** 64 - 1), ints, st.booleans(), st.sampled_from([True, False, None]))
def test_mode_and_safety_words_always_decode(robot_mode, safety_mode, bits, runtime, moving, remote):
    """Any integers in the mode words give a state with a reason when motion is refused."""
    state = controller_state(robot_mode, safety_mode, bits, runtime, moving, remote)
    assert isinstance(state, ControllerState)
    assert state.motion_allowed == (state.reason == "")
    assert isinstance(safety_stop(bits, safety_mode), str)


class _Package:
    """The four status getters of ur-rtde's RTDEReceiveInterface, answering one package's fields."""

    def __init__(self, robot_mode, safety_mode, bits, runtime):
        self.getRobotMode, self.getSafetyMode = lambda: robot_mode, lambda: safety_mode
        self.getSafetyStatusBits, self.getRuntimeState = lambda: bits, lambda: runtime


@FUZZ
@given(ints, ints, st.integers(0, 2 ** 64 - 1), ints)
@example(7, 1, 0, 2)  # RUNNING, NORMAL, no safety bit, PLAYING
@example(7, 3, 1 << 2, 1)  # a protective stop is a state, not corruption
@example(7, 1, 1 << 11, 2)  # a safety status bit UR does not define
def test_status_fields_no_controller_sends_are_a_broken_stream_never_a_state(robot_mode, safety_mode, bits, runtime):
    """state() and the move's status read the fields once (URStatus.read): values outside UR's tables raise
    CommunicationError naming the field, so corrupt data is never reported as a safety stop."""
    known = -1 <= robot_mode <= 8 and 1 <= safety_mode <= 13 and not bits & ~KNOWN_SAFETY_BITS \
        and runtime in RUNTIME_NAMES
    try:
        st_ = URStatus.read(_Package(robot_mode, safety_mode, bits, runtime), "192.0.2.7")
    except CommunicationError as exc:
        assert not known and "192.0.2.7" in str(exc) and "corrupt" in str(exc)
    else:
        assert known and (st_.robot_mode, st_.safety_mode, st_.bits, st_.runtime) == (robot_mode, safety_mode, bits,
                                                                                       runtime)


# -- the simulated controller's RTDE server ----------------------------------------------------------------
@pytest.fixture(scope="module")
def core():
    from payload_agent.fakes.ur.controller import URControllerCore

    ctrl = URControllerCore("127.0.0.1")  # not started: no listeners, no clock; only its RTDE parser is used
    yield ctrl
    ctrl.close()


OUTPUT_NAMES = ["timestamp", "actual_q", "actual_current", "payload", "output_int_register_0", "no_such_field", ""]
INPUT_NAMES = ["input_int_register_0", "input_double_register_1", "input_bit_register_64",
               "input_bit_registers0_to_31", "speed_slider_fraction", "standard_digital_output", "nope"]


def names_payload(names) -> bytes:
    return ("".join(n + "," for n in names)).encode()


client_packages = st.one_of(
    st.builds(lambda p: rp.pack(rp.REQUEST_PROTOCOL_VERSION, p),
              st.sampled_from([struct.pack(">H", 2), struct.pack(">H", 1)]) | st.binary(max_size=4)),
    st.builds(lambda p: rp.pack(rp.GET_URCONTROL_VERSION, p), st.binary(max_size=2)),
    st.builds(lambda f, n, tail: rp.pack(rp.CONTROL_PACKAGE_SETUP_OUTPUTS,
                                         struct.pack(">d", f) + names_payload(n) + tail),
              st.sampled_from([500.0, 125.0, 0.0, -1.0, math.nan, math.inf, 1e9]) | doubles,
              st.lists(st.sampled_from(OUTPUT_NAMES), max_size=4), st.binary(max_size=4)),
    st.builds(lambda p: rp.pack(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, p), st.binary(max_size=12)),
    st.builds(lambda n, tail: rp.pack(rp.CONTROL_PACKAGE_SETUP_INPUTS, names_payload(n) + tail),
              st.lists(st.sampled_from(INPUT_NAMES), max_size=4), st.binary(max_size=3)),
    st.builds(lambda p: rp.pack(rp.CONTROL_PACKAGE_START, p), st.binary(max_size=2)),
    st.builds(lambda p: rp.pack(rp.CONTROL_PACKAGE_PAUSE, p), st.binary(max_size=2)),
    st.builds(lambda rid, p: rp.pack(rp.DATA_PACKAGE, bytes([rid]) + p), st.integers(0, 3), st.binary(max_size=24)),
    st.builds(lambda p: rp.pack(rp.DATA_PACKAGE, p), st.binary(max_size=2)),
    st.builds(lambda k, p: rp.pack(k, p), st.integers(0, 255), st.binary(max_size=16)),
    st.builds(lambda size, k, p: struct.pack(">HB", size, k) + p, st.integers(0, 70000 - 1).map(lambda s: s % 65536),
              st.integers(0, 255), st.binary(max_size=16)),
)
client_streams = st.one_of(st.lists(client_packages, max_size=12).map(b"".join), st.binary(max_size=600))


def split_packages(data: bytes) -> tuple[list[tuple[int, bytes]], bytes]:
    """Complete RTDE packages (kind, payload) at the front of ``data`` and the rest."""
    out, pos = [], 0
    while len(data) - pos >= rp.HEADER_SIZE:
        size, kind = rp.HEADER.unpack_from(data, pos)
        if size < rp.HEADER_SIZE or len(data) - pos < size:
            break
        out.append((kind, data[pos + rp.HEADER_SIZE:pos + size]))
        pos += size
    return out, data[pos:]


def serve(core, data: bytes) -> tuple[list[tuple[int, bytes]], bytes, BaseException | None]:
    """The fake's RTDE handler on one end of a socketpair, ``data`` from the client then EOF:
    (the fake's packages, bytes after the last whole package, how the handler ended)."""
    client, server = socket.socketpair()
    client.settimeout(HANG_S)
    received = bytearray()

    def reader():
        try:
            while chunk := client.recv(65536):
                received.extend(chunk)
        except OSError:
            pass

    rd = threading.Thread(target=reader, daemon=True)
    rd.start()
    client.sendall(data)
    client.shutdown(socket.SHUT_WR)
    end = None
    try:
        bounded(core._serve_rtde, server)  # what the fake's TCP server runs for each connection
    except (ConnectionError, EOFError) as exc:  # the client's EOF: how a session normally ends
        end = exc
    finally:
        server.close()
        rd.join(HANG_S)
        client.close()
    replies, rest = split_packages(bytes(received))
    return replies, rest, end


REPLY_KINDS = {rp.REQUEST_PROTOCOL_VERSION, rp.GET_URCONTROL_VERSION, rp.CONTROL_PACKAGE_SETUP_OUTPUTS,
               rp.CONTROL_PACKAGE_SETUP_INPUTS, rp.CONTROL_PACKAGE_START, rp.CONTROL_PACKAGE_PAUSE, rp.TEXT_MESSAGE}
REQUEST_KINDS = REPLY_KINDS - {rp.TEXT_MESSAGE} | {rp.DATA_PACKAGE}


def check_text_message(payload: bytes) -> None:
    """Protocol version 2 layout: u8 length + message, u8 length + source, u8 warning level."""
    n = payload[0]
    m = payload[1 + n]
    assert len(payload) == 1 + n + 1 + m + 1, payload
    assert payload[-1] in (rp.MSG_EXCEPTION, rp.MSG_ERROR, rp.MSG_WARNING, rp.MSG_INFO)


@FUZZ
@given(client_streams)
def test_fake_rtde_server_answers_any_client_bytes_in_well_framed_rtde(core, data):
    """Every whole client package before any framing loss gets one answer (its reply or a text message),
    except a data package, which is answered only when it is wrong; nothing else comes back."""
    replies, rest, _ = serve(core, data)
    assert rest == b"", f"the fake sent bytes that are not a whole RTDE package: {rest[:32]!r}"
    for kind, payload in replies:
        assert kind in REPLY_KINDS, f"reply of unknown type {kind}"
        if kind == rp.TEXT_MESSAGE:
            check_text_message(payload)
        else:
            assert len(payload) >= 1
    sent, _ = split_packages(data)  # the fake hangs up at a size below the header: nothing after counts
    kinds = [k for k, _ in sent]
    must_answer = [k for k in kinds if k != rp.DATA_PACKAGE]
    assert len(must_answer) <= len(replies) <= len(kinds)
    unknown = sum(k not in REQUEST_KINDS for k in kinds)
    assert sum(k == rp.TEXT_MESSAGE for k, _ in replies) >= unknown
    assert answered_in_order(kinds, [k for k, _ in replies])


def answered_in_order(requests: list[int], replies: list[int]) -> bool:
    """Whether the replies match the requests in order: a non-data request gets one reply of its own kind
    or a text message (a protocol error), a data package none or one text message."""
    M = rp.TEXT_MESSAGE
    ok = {(len(requests), len(replies))}  # (request index, reply index) pairs from which the rest matches
    for i in range(len(requests) - 1, -1, -1):
        k = requests[i]
        for j in range(len(replies), -1, -1):
            one = j < len(replies) and (replies[j] == M or (replies[j] == k and k != rp.DATA_PACKAGE)) \
                and (i + 1, j + 1) in ok
            none = k == rp.DATA_PACKAGE and (i + 1, j) in ok
            if one or none:
                ok.add((i, j))
    return (0, 0) in ok


def test_fake_rtde_server_refuses_a_256th_output_recipe_instead_of_crashing(core):
    """Recipe ids are one byte: after 255 output recipes the next setup is refused (id 0), not a crash."""
    setup = rp.pack(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", 125.0) + names_payload(["timestamp"]))
    data = rp.pack(rp.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)) + setup * 300
    replies, rest, end = serve(core, data)
    assert rest == b"" and isinstance(end, (ConnectionError, EOFError))
    ids = [payload[0] for kind, payload in replies if kind == rp.CONTROL_PACKAGE_SETUP_OUTPUTS]
    assert len(ids) == 300
    assert ids[:255] == list(range(1, 256)) and set(ids[255:]) == {0}


# -- the dashboard server's reply lines (identification) -----------------------------------------------------
class Dashboard:
    """A loopback "dashboard server" on port 29999 of its own 127.x address: a greeting, then ``lines[i]``
    as the reply to the i-th request of each connection; it closes after the last one."""

    def __init__(self):
        from loopback import LoopbackServer, listen_on_own_address
        from payload_agent.drivers.ur_rtde.dashboard import DASHBOARD_PORT

        self.lines: list[bytes] = []
        self._server = LoopbackServer(*listen_on_own_address(DASHBOARD_PORT),
                                      lambda conn: self._serve(conn, list(self.lines)))
        self.host = self._server.host

    @staticmethod
    def _serve(conn, lines):
        conn.settimeout(HANG_S)
        try:
            with conn, conn.makefile("rb") as f:
                conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
                for line in lines:
                    if not f.readline():
                        return
                    conn.sendall(line)
                    if not line.endswith(b"\n"):
                        return  # the reply is cut off by the connection's end (the client would wait for more)
        except OSError:
            pass

    def close(self):
        self._server.close()


@pytest.fixture(scope="module")
def dashboard():
    srv = Dashboard()
    yield srv
    srv.close()


dashboard_lines = st.one_of(
    st.binary(max_size=80).map(lambda b: b + b"\n"), st.binary(max_size=40),
    st.sampled_from([b"URSoftware 5.11.1.108318 (Mar 22 2022)\n", b"URSoftware 3.15.7.106331\n", b"UR5\n",
                     b"20215300042\n", b"true\n", b"false\n", b"URSoftware " + b"9" * 5000 + b".1.1.1\n",
                     "URSoftware \u0665.\u0661\u0661.1.1\n".encode()]))


@settings(FUZZ, max_examples=int(60 * SCALE))
@given(st.lists(dashboard_lines, max_size=4))
@example([b"URSoftware " + b"9" * 5000 + b".1.1.1\n", b"UR5\n"])
def test_dashboard_identification_is_a_value_or_a_communication_error(dashboard, lines):
    from payload_agent.drivers.ur_rtde.dashboard import Identity, dashboard_identify

    dashboard.lines = lines
    try:
        ident = bounded(dashboard_identify, dashboard.host, 1.0)
    except CommunicationError:
        return
    assert isinstance(ident, Identity) and len(ident.version) == 4
    assert ident.info.firmware == ".".join(map(str, ident.version))
