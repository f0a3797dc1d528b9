"""Property-based tests of the CANopen driver's frame decoding (issue 13, "bad input").

The driver is connected once to the simulated arm (its real ``_open``: the nodes, callbacks and
PDO subscriptions as the driver wires them), then the virtual bus is silenced (no notifier, no
SYNC, no SDO watch) and frames are fed one by one through canopen's ``MessageListener``, the very
function python-can's receive thread calls. Arbitrary frames on the drives' COB-IDs (TPDO1, EMCY,
heartbeat, SDO, SYNC, anything) must give samples, recorded EMCYs and NMT states, or the driver's
own protocol error (a monitor fault naming the drive, or CommunicationError from the sample
reader), never an exception inside the receive callbacks: canopen would log and drop it, and
the driver would never learn what the drive sent.

Round trips: the simulated drive's encoding (its canopen object dictionary for the TPDO, canopen's
EMCY producer layout, the NMT heartbeat byte) decodes in the driver to what the drive reported.
"""

from __future__ import annotations

import logging
import math
import os

import can
import pytest
import yaml
from canopen.emcy import EMCY_STRUCT
from canopen.network import MessageListener
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from conftest import ROOT
from payload_agent.configuration.config import parse_config
from payload_agent.drivers.base import MotionLimits, Supervision
from payload_agent.drivers.stream import check_sample as _check_sample
from payload_agent.drivers.canopen.driver import CANopenDriver
from payload_agent.drivers.canopen.cia402 import OPERATION_ENABLED, state_of
from payload_agent.drivers.canopen.pdo import TPDO1, TPDO1_COB
from payload_agent.errors import CommunicationError
from payload_agent.fakes.canopen import SimulatedCANopenArm

# DECODER_FUZZ_SCALE=20 searches 20 times harder (a deep run by hand; the suite keeps the default)
SCALE = float(os.environ.get("DECODER_FUZZ_SCALE", "1"))
FUZZ = settings(max_examples=int(200 * SCALE), deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
EMCY_COB, HEARTBEAT_COB, SDO_RESPONSE_COB, SYNC_COB = 0x80, 0x700, 0x580, 0x80


@pytest.fixture(scope="module")
def rig():
    """(driver, fake, feed): the driver's receive side as ``_open`` wired it, fed by hand."""
    data = yaml.safe_load((ROOT / "configs" / "sim-canopen-arm.yaml").read_text())
    data["simulation"]["time_scale"] = 4.0
    cfg = parse_config(data, source="sim-canopen-arm.yaml")
    fake = SimulatedCANopenArm.from_config(cfg).start()
    drv = CANopenDriver(fake.bound_options(cfg.driver_options),
                        MotionLimits(cfg.robot.max_joint_speed_rad_s, cfg.robot.max_joint_accel_rad_s2),
                        Supervision(max_stream_gap_s=0.5, stop_ack_timeout_s=1.0))
    drv._open()  # the real connect sequence, without the base's reader and watchdog threads
    try:
        watch = getattr(drv, "sdo_watch", None)
        if watch is not None:
            watch.stop()
        drv.sync.stop()
        drv.network.notifier.stop()  # from here on only the frames fed below arrive
        listener = MessageListener(drv.network)
        yield drv, fake, listener
    finally:
        drv._close()
        fake.close()


def reset(drv) -> None:
    """A fresh receive state (the callbacks are bound to these objects: re-initialise them in place)."""
    drv.monitor.__init__(drv.options)
    drv.monitor.expect_operational = True
    drv.monitor.operational = [True] * drv.n
    drv.tpdo.__init__(drv.n)


class CallbackErrors(logging.Handler):
    """canopen's MessageListener logs, and drops, any exception a receive callback raises."""

    def __init__(self):
        super().__init__(logging.ERROR)
        self.records: list[str] = []

    def emit(self, record):
        self.records.append(record.getMessage())


@pytest.fixture
def callback_errors():
    handler = CallbackErrors()
    logger = logging.getLogger("canopen.network")
    logger.addHandler(handler)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)


def feed(listener, frames, t0: float = 100.0) -> None:
    for i, (cob, data) in enumerate(frames):
        listener.on_message_received(can.Message(arbitration_id=cob, data=bytes(data), is_extended_id=False,
                                                 timestamp=t0 + 0.004 * i))


NODES = [1, 2, 3, 4, 5, 6]
node = st.sampled_from(NODES)
payload = st.binary(max_size=8)
tpdo_payload = st.builds(TPDO1.pack, st.integers(0, 0xFFFF), st.integers(-2 ** 31, 2 ** 31 - 1),
                         st.integers(-2 ** 15, 2 ** 15 - 1))
frames = st.lists(st.one_of(
    st.tuples(node.map(lambda n: TPDO1_COB + n), tpdo_payload | payload),
    st.tuples(node.map(lambda n: EMCY_COB + n), st.builds(EMCY_STRUCT.pack, st.integers(0, 0xFFFF),
                                                          st.integers(0, 255), st.binary(max_size=5)) | payload),
    st.tuples(node.map(lambda n: HEARTBEAT_COB + n), st.sampled_from([b"\x05", b"\x85", b"\x7f", b"\x04", b"\x00"])
              | payload),
    st.tuples(node.map(lambda n: SDO_RESPONSE_COB + n), payload),
    st.tuples(st.sampled_from([SYNC_COB, 0, 0x100]), payload),
    st.tuples(st.integers(0, 0x7FF), payload),
), max_size=30)


def malformed(cob: int, data: bytes) -> str | None:
    """What a frame on a drive's COB-ID breaks, by CiA 301 (None: nothing)."""
    kind, nid = cob & 0x780, cob & 0x7F
    if nid not in NODES:
        return None
    if kind == TPDO1_COB and len(data) != TPDO1.size:
        return "tpdo"
    if cob - nid == EMCY_COB and len(data) != 8:
        return "emcy"
    if kind == HEARTBEAT_COB and len(data) == 0:
        return "heartbeat"
    return None


@FUZZ
@given(frames)
@example([(EMCY_COB + 2, b"\x10\x82")])  # a short EMCY
@example([(HEARTBEAT_COB + 3, b"")])  # an empty heartbeat
@example([(TPDO1_COB + 4, b"\x37\x06\x00")])  # a short TPDO
@example([(HEARTBEAT_COB + 1, b"\x79"), (0, b"\x01\x00")])  # a state canopen has no name for, then "start all"
def test_any_frames_give_values_or_the_drivers_protocol_error(rig, callback_errors, frames):
    drv, _, listener = rig
    reset(drv)
    callback_errors.records.clear()
    raised = []
    for i, frame in enumerate(frames):  # one at a time, to know which frame a logged error came from
        before = len(callback_errors.records)
        feed(listener, [frame], t0=100.0 + 0.004 * i)
        raised += [frame] * (len(callback_errors.records) - before)
    # an NMT command (COB-ID 0) comes from another master, not a drive, and canopen's own NMT bookkeeping may log
    # and drop it, which the driver need not know about: a short one, or any state change after a garbage heartbeat
    # left canopen a state it has no name for (its log call raises KeyError; found by this test in CI, session 19)
    assert all(cob == 0 for cob, _ in raised), f"a receive callback raised (canopen dropped the frame): " \
                                               f"{raised} {callback_errors.records}"
    broken = [m for m in (malformed(c, d) for c, d in frames) if m]
    if "tpdo" in broken:
        assert drv.tpdo.error is not None
    if {"emcy", "heartbeat"} & set(broken):
        assert drv.monitor.fault is not None
    for _ in range(len(frames) + 1):  # every set of six TPDOs is one sample
        try:
            sample = drv._read_sample(0.0)
            if sample is None:
                break
            _check_sample(sample, 6)
        except CommunicationError:
            break
        assert all(math.isfinite(v) for v in (sample.t_ctrl, *sample.q, *sample.effort))
    if drv.monitor.fault is not None:
        assert isinstance(drv.monitor.fault, str) and ("joint" in drv.monitor.fault or "drive" in drv.monitor.fault)


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 0xFFFF), st.integers(-2 ** 31, 2 ** 31 - 1),
                          st.integers(-2 ** 15, 2 ** 15 - 1)), min_size=6, max_size=6))
def test_tpdos_encoded_by_the_simulated_drives_decode_to_the_same_sample(rig, values):
    """The drive's object dictionary encodes statusword, position and effort (as it builds its TPDO1);
    the driver's sample is the same numbers in its units."""
    drv, fake, listener = rig
    reset(drv)
    o = drv.options
    frames = []
    for j, (sw, pos, eff) in enumerate(values):
        od = fake.drives[j].node.object_dictionary
        data = (od[0x6041].encode_raw(sw) + od[0x6064].encode_raw(pos)
                + od[0x6077 if o.effort_object == "torque" else 0x6078].encode_raw(eff))
        frames.append((TPDO1_COB + o.node_ids[j], data))
    feed(listener, frames)
    sample = drv._read_sample(0.0)
    assert sample is not None
    for j, (sw, pos, eff) in enumerate(values):
        assert drv.monitor.statusword[j] == sw and drv.monitor.position[j] == pos
        assert sample.q[j] == pytest.approx(o.direction[j] * (pos - o.zero_counts[j]) / o.counts_per_rad[j])
        assert sample.effort[j] == pytest.approx(o.direction[j] * eff * drv.effort_per_permille[j])


@FUZZ
@given(node, st.integers(0, 0xFFFF), st.integers(0, 255), st.binary(max_size=5))
def test_emcy_as_the_simulated_drive_sends_it_is_recorded_and_faults_unless_a_reset(rig, nid, code, register, extra):
    drv, _, listener = rig
    reset(drv)
    feed(listener, [(EMCY_COB + nid, EMCY_STRUCT.pack(code, register, extra))])  # canopen's EmcyProducer.send
    j = drv.options.node_ids.index(nid)
    assert drv.monitor.emcy == [(j, code, register)]
    assert (drv.monitor.fault is not None) == bool(code & 0xFF00)
    if code & 0xFF00:
        assert f"0x{code:04X}" in drv.monitor.fault and drv.labels[j] in drv.monitor.fault


@pytest.mark.parametrize("state, byte, fault", [("OPERATIONAL", 0x05, False), ("OPERATIONAL toggle", 0x85, False),
                                                ("PRE-OPERATIONAL", 0x7F, True), ("STOPPED", 0x04, True),
                                                ("boot-up", 0x00, True)])
def test_heartbeat_states_decode(rig, state, byte, fault):
    drv, _, listener = rig
    reset(drv)
    feed(listener, [(HEARTBEAT_COB + 5, bytes([byte]))])
    j = drv.options.node_ids.index(5)
    assert drv.monitor.nmt_state[j] == byte & 0x7F
    assert (drv.monitor.fault is not None) == fault


def test_statusword_decoding_covers_every_word():
    """Any 16-bit statusword names a CiA 402 state or says it is unknown (with the word)."""
    names = {state_of(sw) for sw in range(1 << 16)}
    assert OPERATION_ENABLED in names
    assert all(n in {"NOT READY TO SWITCH ON", "SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON",
                     OPERATION_ENABLED, "QUICK STOP ACTIVE", "FAULT REACTION ACTIVE", "FAULT"}
               or n.startswith("UNKNOWN (statusword 0x") for n in names)
    assert state_of(0x0637) == OPERATION_ENABLED  # as the simulated drive reports it (remote, target reached)
