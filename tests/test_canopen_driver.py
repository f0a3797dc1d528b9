"""The canopen driver against six simulated CiA 402 drives on python-can's virtual bus (real canopen client).

Supervision limits are relaxed where a test is not about them, so that a busy machine's pauses
do not trip it; nothing here asserts on wall time or on a sample count a loaded scheduler might
not deliver.
"""

import logging
import math
import threading
import time

import numpy as np
import pytest
import yaml

from conftest import ROOT
from payload_agent.configuration.config import parse_config
from payload_agent.drivers.base import MotionLimits, Supervision
from payload_agent.drivers.canopen.driver import CANopenDriver
from payload_agent.errors import CommunicationError, ConfigError, MotionAbortedError, SupervisionTrip
from payload_agent.fakes.canopen import SimulatedCANopenArm

SIM = ROOT / "configs" / "sim-canopen-arm.yaml"
RELAXED = Supervision(max_stream_gap_s=0.5, stop_ack_timeout_s=1.0)
START = np.radians([0, -60, 60, -150, -30, 0])
TARGET = START + np.radians([0, 12, -8, 0, 0, 6])
SPEED, ACCEL = math.radians(30), math.radians(120)
SLOW = math.radians(3)  # fault tests: the move lasts 4 s simulated, 1 s wall, so the fault lands mid-move


def config(time_scale=4.0, **driver):
    data = yaml.safe_load(SIM.read_text())
    data["simulation"]["time_scale"] = time_scale
    # SDO replies may wait 2 s (the driver's default is 0.5 s): the simulated drives answer from a process a CI
    # machine with both cores busy can starve for longer than that while the rig connects (set-ups failed with "stopped
    # answering SDO" in sessions 23 and 24); tests about a missing or late reply set their own limits
    data["driver"].update({"heartbeat_ms": 50, "heartbeat_timeout_ms": 400, "sdo_timeout_s": 2.0, **driver})
    return parse_config(data, source="sim-canopen-arm.yaml")


def with_rig(**kw):
    return pytest.mark.parametrize("rig", [kw], indirect=True, ids=[""])


@pytest.fixture
def rig(request):
    """(driver, fake): a started simulated arm and a connected driver; options via ``with_rig(...)``."""
    kw = dict(getattr(request, "param", {}))
    supervision = kw.pop("supervision", RELAXED)
    fake_kw = kw.pop("fake", {})
    cfg = config(**kw)
    fake = SimulatedCANopenArm.from_config(cfg, **fake_kw).start()
    drv = CANopenDriver(fake.bound_options(cfg.driver_options),
                        MotionLimits(cfg.robot.max_joint_speed_rad_s, cfg.robot.max_joint_accel_rad_s2), supervision)
    try:
        drv.connect()
        yield drv, fake
    finally:
        drv.close()
        fake.close()


def move_with_fault(drv, fake, fault, delay_s=0.15, **params):
    """Start a move, inject ``fault`` ``delay_s`` after its set-points reached the drives (the power-up before
    them takes longer on a loaded host); (exception, fault time, samples)."""
    samples = []
    drv.start_stream(samples.append)
    t_fault = []
    t_call = time.monotonic()

    def inject():
        deadline = time.monotonic() + 5.0
        while not any(e.kind == "move" and e.t >= t_call for e in list(fake.events)) and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(delay_s)
        t_fault.append(time.monotonic())
        fake.inject_fault(fault, **params)
    timer = threading.Thread(target=inject, daemon=True)
    timer.start()
    with pytest.raises((SupervisionTrip, MotionAbortedError)) as exc:
        drv.move_joints(TARGET, SLOW, ACCEL, 30.0)
    timer.join()
    return exc.value, t_fault[0], samples


def stops_after(fake, t):
    """Node ids that received a quick stop command at or after monotonic time ``t``."""
    return {int(e.detail.split(":")[0].split()[1]) for e in fake.events if e.kind == "stop" and e.t >= t
            and "quick stop in" in e.detail}


def self_stops_after(fake, t):
    """Node ids that stopped themselves on losing the agent's heartbeat (node 127) at or after ``t``."""
    return {int(e.detail.split(":")[0].split()[1]) for e in fake.events if e.kind == "stop" and e.t >= t
            and "heartbeat of node 127 lost" in e.detail and "quick stop (0x6007 = 3)" in e.detail}


POWER_COMMANDS = {0x06, 0x07, 0x0F}  # shutdown, switch on, enable operation (CiA 402 transitions 2, 3, 4)


def test_connecting_and_reading_never_energise_the_drives_the_first_move_does(rig):
    """The power state machine runs at the template's activation (the first move), never at connect: a
    session that only reads (doctor, plan --connect, watch) leaves every power stage off."""
    drv, fake = rig
    drv.identify(), drv.state()
    drv.start_stream(lambda s: None)
    drv.wait_sample(10.0)
    assert all(d.state == "SWITCH ON DISABLED" and not d.history for d in fake.drives)
    drv.move_joints(TARGET, SPEED, ACCEL, 30.0)
    for d in fake.drives:
        assert d.state == "OPERATION ENABLED"
        assert [cw for cw, _ in d.history if cw in POWER_COMMANDS][:3] == [0x06, 0x07, 0x0F]


def test_doctor_leaves_the_drives_unpowered(tmp_path, monkeypatch):
    from payload_agent.session.doctor import run_doctor
    from payload_agent.session.simulation import SimulatedCell

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    cfg = config()
    cell = SimulatedCell(cfg).start()
    try:
        report = run_doctor(cfg, cell=cell, stream_window_s=0.5)
        drives = [(d.state, list(d.history)) for d in cell.controller.drives]
    finally:
        cell.close()
    assert next(c for c in report.checks if c.name == "state").status == "ok", report.checks
    assert drives and all(state == "SWITCH ON DISABLED" and not history for state, history in drives), drives


def test_connect_configures_pdos_and_streams_one_sample_per_sync(rig):
    drv, fake = rig
    info = drv.identify()
    assert "CiA 402" in info.model and info.serial.count("/") == 5
    st = drv.state()
    assert st.motion_allowed and "SWITCH ON DISABLED" in st.detail
    for d in fake.drives:  # the layout the driver wrote over SDO, as the drive holds it
        cob, valid, ttype, entries = d.tpdos()[0]
        assert (cob, valid, ttype) == (0x180 + d.node_id, True, 1)
        assert [e[0] for e in entries] == [0x6041, 0x6064, 0x6077]
        assert not any(valid for _, valid, _, _ in d.tpdos()[1:])
        assert d.node.sdo[0x1017].raw == 50
        # the drive consumes the agent's heartbeat (node 127, the YAML's consumer time) and quick-stops when
        # it is lost
        consumer_ms = drv.options.master_heartbeat_timeout_ms
        assert d.node.sdo[0x1016][1].raw == 127 << 16 | consumer_ms and d.node.sdo[0x6007].raw == 3
        assert d.consumer_state == "active"
        # the move's profile values travel in synchronous RPDOs with its set-points, not over SDO
        rpdos = d.rpdos()
        assert rpdos[0x400 + d.node_id] == (1, [(0x6081, 0, 32), (0x6083, 0, 32)])
        assert rpdos[0x500 + d.node_id] == (1, [(0x6084, 0, 32)])
    samples = []
    drv.start_stream(samples.append)
    syncs0 = fake.sync_count - fake.skipped_syncs
    time.sleep(1.0)
    drv.stop_stream()
    answered = fake.sync_count - fake.skipped_syncs - syncs0
    assert answered > 0 and len(samples) >= 0.9 * answered - 2  # every answered SYNC became one sample
    t = np.array([s.t_ctrl for s in samples])
    assert np.all(np.diff(t) > 0)  # bus timestamps, in order
    # the simulated wire runs on the simulated clock: SYNCs 1/250 s apart arrive time_scale/250 apart
    assert np.median(np.diff(t)) == pytest.approx(4.0 / 250.0, rel=0.5)
    q = np.array(samples[-1].q)
    assert np.max(np.abs(q - START)) < 1e-4  # where the arm stands, with the encoders' noise
    wall = samples[-1].t_recv - samples[0].t_recv
    print(f"\nPDO stream: {len(samples)} samples in {wall:.2f} s wall = {(len(samples) - 1) / wall:.0f} Hz "
          f"(SYNC 250 Hz; {answered} SYNCs answered)")


def test_move_enables_through_the_state_machine_and_joints_arrive_together(rig):
    drv, fake = rig
    drv.start_stream(lambda s: None)
    drv.wait_sample(10.0)  # the driver refuses to move before its first sample
    drv.move_joints(TARGET, SPEED, ACCEL, 30.0)
    for d in fake.drives:
        states = [s for _, s in d.history]
        assert states[:3] == ["READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"], d.history
        assert [cw for cw, _ in d.history[:3]] == [0x06, 0x07, 0x0F]
        assert d.mode == 1
    moved = [d for d in fake.drives if d.end_t is not None]
    assert [d.joint for d in moved] == [1, 2, 5]  # joints 2, 3, 6
    ends = [d.end_t for d in moved]
    assert max(ends) - min(ends) < 1e-3  # scaled profile velocities: one arrival time
    s = drv.wait_sample(2.0, after=time.monotonic())
    assert np.max(np.abs(np.array(s.q) - TARGET)) < math.radians(0.02)
    assert all(d.state == "OPERATION ENABLED" for d in fake.drives)
    # effort: per mille of the rated torque the drive reports (0x6076), in N·m, with the YAML's direction
    s_fake = fake.robot.snapshot()
    assert np.max(np.abs(np.array(s.effort) - s_fake.torque_nm)) < 0.5
    assert abs(s.effort[1]) > 1.0  # joint 2 holds the arm against gravity


@with_rig(fake={"faulted": {3: 0x8611}})
def test_a_drive_starting_in_fault_is_reported_and_not_touched(rig):
    drv, fake = rig
    st = drv.state()
    assert not st.motion_allowed
    assert "joint 3 (node 3) is in FAULT" in st.reason and "0x8611 (following error)" in st.reason
    assert "clear_faults" in st.reason
    with pytest.raises(Exception, match="joint 3 \\(node 3\\)"):
        drv.move_joints(TARGET, SPEED, ACCEL, 30.0)
    assert not [e for e in fake.events if e.kind == "move"]
    assert fake.drives[2].state == "FAULT" and not any(cw & 0x80 for cw, _ in fake.drives[2].history)


@with_rig(fake={"faulted": {3: 0x8611}}, clear_faults=True)
def test_clear_faults_resets_a_faulted_drive_and_says_so(rig, caplog):
    drv, fake = rig
    assert fake.drives[2].state == "SWITCH ON DISABLED"
    assert (0x80, "SWITCH ON DISABLED") in fake.drives[2].history
    st = drv.state()
    assert st.motion_allowed and "joint 3 (node 3) was in FAULT at connect (error code 0x8611" in st.detail
    drv.start_stream(lambda s: None)
    drv.wait_sample(10.0)  # the driver refuses to move before its first sample
    drv.move_joints(TARGET, SPEED, ACCEL, 30.0)


def test_clear_faults_warns(caplog):
    cfg = config(clear_faults=True)
    fake = SimulatedCANopenArm.from_config(cfg, faulted={5: 0x2310}).start()
    drv = CANopenDriver(fake.bound_options(cfg.driver_options), MotionLimits(3.0, 3.0), RELAXED)
    try:
        with caplog.at_level(logging.WARNING, logger="payload_agent.drivers.canopen.driver"):
            drv.connect()
        assert any("joint 5 (node 5) was in FAULT" in r.message and "clear_faults" in r.message
                   for r in caplog.records)
    finally:
        drv.close()
        fake.close()


def test_drive_fault_mid_sweep_quick_stops_every_drive_and_keeps_data(rig):
    drv, fake = rig
    exc, t_fault, samples = move_with_fault(drv, fake, "protective_stop", joint=2)
    msg = str(exc)
    assert "joint 2 (node 2)" in msg and "0x8611" in msg, msg
    assert stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}
    report = drv.last_stop_report
    assert report is not None and report.acknowledged, report
    first_stop = min(e.t for e in fake.events if e.kind == "stop" and e.t >= t_fault)
    assert first_stop - t_fault < 0.5
    # data kept: the stream never failed and kept delivering samples after the stop
    assert drv.stream_error is None
    n = len(samples)
    drv.wait_sample(2.0, after=time.monotonic())
    assert len(samples) > n and any(s.t_recv < t_fault for s in samples)
    assert drv.monitor.fault.startswith("EMCY from joint 2 (node 2)")
    with pytest.raises(MotionAbortedError, match="fault is pending"):  # nothing moves after it
        drv.move_joints(START, SPEED, ACCEL, 30.0)


def test_heartbeat_loss_aborts_the_move(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "drop_connections", joint=5, heartbeat_only=True)
    msg = str(exc)
    assert "heartbeat lost from joint 5 (node 5)" in msg and "0x8130" in msg, msg
    assert stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}  # the drive still hears: its heartbeat alone stopped
    assert drv.last_stop_report.acknowledged


def test_a_drive_cut_off_the_bus_stops_itself_and_its_stop_is_not_confirmed(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "drop_connections", joint=4)
    msg = str(exc)
    # the drive's silence among the others names it; a pause of this whole process as long as the stream
    # limit (a busy machine) lets the stall watchdog trip first
    assert "joint 4 (node 4)" in msg or "stream stalled" in msg, msg
    assert stops_after(fake, t_fault) == {1, 2, 3, 5, 6}  # node 4 hears nothing the agent sends...
    assert self_stops_after(fake, t_fault) == {4}  # ... and stops itself once the agent's heartbeat is lost
    report = drv.last_stop_report
    assert not report.acknowledged and "NOT acknowledged" in report.describe()


def test_a_cut_bus_stops_every_drive_by_the_heartbeat_it_no_longer_hears(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "drop_connections")
    assert "stalled" in str(exc) or "heartbeat lost" in str(exc), str(exc)
    assert stops_after(fake, t_fault) == set()  # no quick stop of the agent's reaches them
    assert self_stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}
    assert not drv.last_stop_report.acknowledged
    deadline = time.monotonic() + 10.0  # the arm ramps down at the drives' quick stop deceleration (0x6085)
    while fake.robot.snapshot().moving and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not fake.robot.snapshot().moving
    assert all(d.state in ("QUICK STOP ACTIVE", "SWITCH ON DISABLED") for d in fake.drives)


def test_the_drives_judge_the_agents_heartbeat_on_bus_time_from_its_first_heartbeat():
    """A drive's consumer heartbeat: monitoring starts with the first heartbeat; the heartbeat's age is measured
    on the bus (the master's send times), so a pause of the process that delays both alike is no loss."""
    fake = SimulatedCANopenArm.from_config(config())  # not started: no bus, the drive alone
    d = fake.drives[0]
    d.node.sdo[0x1016][1].raw = 127 << 16 | 150
    d.node.sdo[0x6007].raw = 3
    with pytest.raises(Exception, match="0x06090030|[Vv]alue range"):
        d.node.sdo[0x6007].raw = 7  # not a reaction CiA 402 defines
    d.state = "SWITCHED ON"
    d.check_consumer(100.0)
    assert d.consumer_state == "unknown"  # no heartbeat heard yet: nothing to miss
    d.on_heartbeat_of(5, 100.0)  # another node's heartbeat
    assert d.consumer_state == "unknown"
    d.on_heartbeat_of(127, 100.0)
    d.check_consumer(100.14)  # a SYNC sent 140 ms after the heartbeat (however late it arrives): in time
    assert d.consumer_state == "active" and d.state == "SWITCHED ON"
    d.silent = True  # cut off the bus: the next heartbeat never reaches it
    d.on_heartbeat_of(127, 100.2)
    d.check_consumer(100.16)
    assert d.consumer_state == "timeout" and d.state == "SWITCH ON DISABLED"  # quick stop: transition 7
    assert [e.kind for e in fake.events] == ["heartbeat lost"]  # it was not moving: nothing to stop


def test_a_late_sdo_server_mid_move_trips_and_stops_every_drive(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "slow_reply", delay_s=0.15)
    msg = str(exc)
    assert isinstance(exc, SupervisionTrip) and "no SDO reply from joint" in msg, msg
    assert "replies late or not at all" in msg
    assert stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}
    assert drv.last_stop_report.acknowledged  # the PDOs still run: the statuswords confirm it
    assert not [e for e in fake.events if e.kind == "move" and e.t > t_fault]


def test_no_set_point_goes_out_while_a_drive_leaves_sdo_unanswered(rig):
    drv, fake = rig
    drv.start_stream(lambda s: None)
    drv.wait_sample(10.0)  # the driver refuses to move before its first sample
    drv.move_joints(TARGET, SPEED, ACCEL, 30.0)  # enabled, one move done
    t_fault = time.monotonic()
    fake.inject_fault("no_reply")
    with pytest.raises(SupervisionTrip, match="no SDO reply from joint"):
        drv.move_joints(START, SPEED, ACCEL, 30.0)
    assert not [e for e in fake.events if e.kind == "move" and e.t > t_fault]
    assert stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}


def test_a_drive_leaving_operation_enabled_aborts(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "leave_remote", joint=6)
    assert "joint 6 (node 6) left OPERATION ENABLED" in str(exc) and "SWITCH ON DISABLED" in str(exc)
    assert stops_after(fake, t_fault) >= {1, 2, 3, 4, 5}


@with_rig(supervision=Supervision(max_stream_gap_s=0.3, stop_ack_timeout_s=1.0))
def test_malformed_pdo_and_stalled_stream_stop_the_arm(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "garbage", joint=3)
    assert isinstance(exc, SupervisionTrip) and "TPDO1 from joint 3 (node 3) has 5 data bytes" in str(exc)
    assert stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}
    assert isinstance(drv.stream_error, CommunicationError)


@with_rig(supervision=Supervision(max_stream_gap_s=0.3, stop_ack_timeout_s=1.0))
def test_stalled_stream_trips_the_watchdog_and_the_stop_is_confirmed_over_sdo(rig):
    drv, fake = rig
    exc, t_fault, _ = move_with_fault(drv, fake, "stall_stream")
    assert "stalled" in str(exc) or "stopped sending its TPDO" in str(exc)
    assert stops_after(fake, t_fault) == {1, 2, 3, 4, 5, 6}
    assert drv.last_stop_report.acknowledged  # no TPDO to confirm it, so the statuswords came over SDO


@with_rig(supervision=Supervision(max_stream_gap_s=0.1, stop_ack_timeout_s=1.0))
def test_a_trip_while_the_drives_are_being_enabled_sends_no_set_point(rig):
    drv, fake = rig
    drv.start_stream(lambda s: None)
    drv.wait_sample(1.0, after=time.monotonic())
    fake.inject_fault("stall_stream")  # the enable steps wait for statuswords that never come
    with pytest.raises(SupervisionTrip, match="stalled"):
        drv.move_joints(TARGET, SPEED, ACCEL, 30.0)
    time.sleep(0.1)
    assert not [e for e in fake.events if e.kind == "move"]
    assert all(d.end_t is None for d in fake.drives)


def test_never_finishing_move_times_out_and_stops(rig):
    drv, fake = rig
    drv.start_stream(lambda s: None)
    fake.inject_fault("never_finish")
    t0 = time.monotonic()
    with pytest.raises(MotionAbortedError, match="did not report"):  # the base's finish watchdog, or our timeout
        drv.move_joints(TARGET, SPEED, ACCEL, 3.0)
    assert stops_after(fake, t0) == {1, 2, 3, 4, 5, 6}


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")  # python-can's receive thread
def test_quick_stop_over_a_new_bus_when_the_old_one_is_gone(rig):
    """Our move under way and the driver's bus object gone (adapter unplugged and back): the supervision
    quick-stops every drive over a new bus. A stop after our move had finished sends nothing at all."""
    drv, fake = rig
    drv.start_stream(lambda s: None)
    drv.wait_sample(10.0)  # the driver refuses to move before its first sample
    drv.move_joints(TARGET, SPEED, ACCEL, 30.0)
    t_done = time.monotonic()
    assert drv.stop() is False and stops_after(fake, t_done) == set()  # nothing of ours runs: nothing is sent
    ended: list[BaseException] = []

    def move_back() -> None:
        try:
            drv.move_joints(START, SLOW, ACCEL, 60.0)
        except BaseException as exc:  # noqa: BLE001 - asserted below
            ended.append(exc)

    mover = threading.Thread(target=move_back, daemon=True)
    mover.start()
    deadline = time.monotonic() + 10.0
    while float(np.max(np.abs(np.asarray(drv.latest_sample.q) - TARGET))) < math.radians(0.3):
        assert time.monotonic() < deadline, "the move back did not start"
        time.sleep(0.01)
    t0 = time.monotonic()
    drv.network.bus.shutdown()  # the driver's bus object is gone mid-move
    mover.join(15.0)
    assert not mover.is_alive() and len(ended) == 1 and isinstance(ended[0], SupervisionTrip), ended
    assert stops_after(fake, t0) == {1, 2, 3, 4, 5, 6}
    assert all(d.state in ("QUICK STOP ACTIVE", "SWITCH ON DISABLED") for d in fake.drives)


def test_no_sdo_reply_at_connect_names_the_drive():
    cfg = config(sdo_timeout_s=0.1)
    fake = SimulatedCANopenArm.from_config(cfg).start()
    fake.inject_fault("no_reply")
    drv = CANopenDriver(fake.bound_options(cfg.driver_options), MotionLimits(3.0, 3.0), RELAXED)
    try:
        with pytest.raises(CommunicationError, match=r"joint 1 \(node 1\) did not answer an SDO request"):
            drv.connect()
    finally:
        drv.close()
        fake.close()


def test_rated_torque_comes_from_the_drive_or_the_yaml():
    limits = MotionLimits(3.0, 3.0)
    cfg = config(rated_torque_nm=[56, 50, 28, 12, 12, 12])  # joint 2 disagrees with its drive (56 N·m)
    fake = SimulatedCANopenArm.from_config(cfg).start()
    drv = CANopenDriver(fake.bound_options(cfg.driver_options), limits, RELAXED)
    try:
        with pytest.raises(ConfigError, match=r"driver.rated_torque_nm\[1\].*joint 2 \(node 2\) reports 56 N·m"):
            drv.connect()
    finally:
        drv.close()
        fake.close()
    for yaml_rated, ok in ((None, False), ([56, 56, 28, 12, 12, 12], True)):
        cfg = config(rated_torque_nm=yaml_rated)
        fake = SimulatedCANopenArm.from_config(cfg, has_rated_torque=False).start()
        drv = CANopenDriver(fake.bound_options(cfg.driver_options), limits, RELAXED)
        try:
            if ok:
                drv.connect()
                assert drv.effort_per_permille == pytest.approx([0.056, 0.056, 0.028, 0.012, 0.012, 0.012])
            else:
                with pytest.raises(ConfigError, match=r"driver.rated_torque_nm: joint 1 \(node 1\) has no rated"):
                    drv.connect()
        finally:
            drv.close()
            fake.close()


@with_rig(effort_object="current")
def test_current_actual_is_scaled_by_the_rated_current_the_drive_reports(rig):
    drv, fake = rig
    assert drv.effort_unit == "A"
    assert drv.effort_per_permille == pytest.approx([0.0056, 0.0056, 0.0028, 0.0012, 0.0012, 0.0012])  # 0x6075 mA
    for d in fake.drives:
        assert [e[0] for e in d.tpdos()[0][3]] == [0x6041, 0x6064, 0x6078]
    drv.start_stream(lambda s: None)
    drv.wait_sample(10.0)  # the driver refuses to move before its first sample
    drv.move_joints(TARGET, SPEED, ACCEL, 30.0)
    s = drv.wait_sample(2.0, after=time.monotonic())
    # the simulated joints' torque constant is 10 N·m/A: current = torque / 10
    assert np.max(np.abs(10 * np.array(s.effort) - fake.robot.snapshot().torque_nm)) < 0.5
