"""The modbus driver against the simulated Modbus robot over a real pymodbus TCP connection on loopback.

Faults follow the simulated-controller contract: exception replies, timeouts (no reply, slow reply),
a server that drops every connection mid-sweep, garbage values, a stalled stream, safety stops,
the pendant taking control, a program that never reports done.
"""

import math
import time

import numpy as np
import pytest

from payload_agent.drivers.base import MotionLimits, Supervision
from payload_agent.drivers.modbus.driver import ModbusDriver
from payload_agent.drivers.modbus.options import parse_modbus_options, resolve_map
from payload_agent.errors import CommunicationError, MotionAbortedError, SupervisionTrip, UnsupportedCapability
from payload_agent.fakes.arms import ur5e_spec
from payload_agent.fakes.modbus.controller import SimulatedModbusRobot
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import PayloadSetting

from host_stall import assert_latency_within

Q0 = np.radians([0, -60, 60, -150, -30, 0])  # negative angles: the revolution counters read 65535
GAINS = [10.4, 10.2, 9.8, 10.1, 9.9, 10.0]
LIMITS = MotionLimits(math.radians(180), math.radians(180))
RELAXED = Supervision(max_stream_gap_s=0.3)  # tests that are not about the watchdog survive a busy machine


def _start(preset="ur_modbus_server", **opts):
    # a reply may take 1 s (the driver's default is 0.25 s): the simulated server's thread can be starved for longer
    # on a CI machine with both cores busy (a connect failed so in session 24); tests of late replies set their own
    raw = {"type": "modbus", "host": "127.0.0.1", "preset": preset, "timeout_s": 1.0, **opts}
    options = parse_modbus_options(raw)
    robot = SimRobot(ur5e_spec(), q0_rad=Q0, tick_s=0.008, noise_nm=0.3, seed=3)
    fake = SimulatedModbusRobot(robot, resolve_map(options), gains=GAINS, owns_robot=True).start()
    return fake, fake.bound_options(options)


@pytest.fixture
def ur():
    fake, options = _start()
    yield fake, options
    fake.close()


def _driver(options, supervision=RELAXED):
    drv = ModbusDriver(options, LIMITS, supervision)
    drv.connect()
    drv.wait_sample(2.0)
    return drv


def _sweep_target(start, joint=1, deg=25.0):
    target = np.array(start, float)
    target[joint] += math.radians(deg)
    return target


def test_identify_state_pose_and_stream(ur):
    fake, options = ur
    drv = _driver(options)
    try:
        info = drv.identify()
        assert info.vendor == "Universal Robots" and info.firmware == "5.15"
        assert info.serial == ""  # a register map has no serial; never the address (a new port is the same robot)
        assert "502" not in info.model and f":{options.port}" in drv.describe_endpoint()  # the port it really uses
        st = drv.state()
        assert st.motion_allowed and not st.moving and "robot_mode=7" in st.detail
        s = drv.wait_sample(1.0)
        assert np.allclose(s.q, Q0, atol=0.0011)  # 1 mrad registers, negative angles through the counters
        assert s.t_ctrl is None  # UR's map has no controller clock: timed on receipt
        torque = np.asarray(s.effort) * GAINS
        assert np.allclose(torque, fake.robot.snapshot().torque_nm, atol=1.5)  # mA steps, noise
        pose = drv.flange_pose()
        T = Kinematics(ur5e_spec().dh).flange(np.asarray(s.q))
        assert np.allclose(pose.position_m, T[:3, 3], atol=3e-4)  # 0.1 mm registers
        assert np.allclose(np.asarray(pose.rotation), T[:3, :3], atol=3e-3)  # mrad registers
        assert drv.reports_flange_pose
    finally:
        drv.close()


def test_move_streams_samples_and_logs_the_command(ur):
    fake, options = ur
    drv = _driver(options)
    got = []
    try:
        drv.begin_stats()
        drv.start_stream(got.append)
        target = _sweep_target(Q0)
        t0 = time.monotonic()
        drv.move_joints(target, 0.6, 2.0, 10.0)
        stats = drv.end_stats()
        assert np.allclose(drv.wait_sample(1.0).q, target, atol=0.002)
        moves = [e for e in fake.events if e.kind == "move" and e.t >= t0]
        assert len(moves) == 1 and moves[0].detail == "cmd_seq=1"
        assert stats.count == len(got) > 10 and stats.achieved_rate_hz > 0
        q2 = np.array([s.q[1] for s in got])
        assert q2[-1] - q2[0] == pytest.approx(math.radians(25), abs=0.003)
        assert len({s.t_recv for s in got}) == len(got)  # every sample is a new one
    finally:
        drv.close()


def test_exception_reply_fails_the_stream_and_names_the_registers(ur):
    fake, options = ur
    drv = _driver(options)
    try:
        t0 = time.monotonic()
        fake.inject_fault("garbage", mode="exception")
        with pytest.raises(SupervisionTrip) as info:
            drv.move_joints(_sweep_target(Q0), 0.3, 2.0, 10.0)
        assert "exception 4 (server device failure)" in str(drv.stream_error)
        assert "holding 270-325" in str(drv.stream_error)
        report = info.value.stop_report
        assert report.acknowledged and report.stop_delay_s < 0.5
        stop = fake.first_event_after("stop", t0)
        assert stop is not None
    finally:
        drv.close()


def test_garbage_values_are_refused_naming_the_register(ur):
    fake, options = ur
    drv = _driver(options)
    try:
        fake.inject_fault("garbage", mode="values")
        deadline = time.monotonic() + 2.0
        while drv.stream_error is None and time.monotonic() < deadline:
            time.sleep(0.01)
        err = str(drv.stream_error)
        assert "impossible joint_angles" in err and "revolution counter 32" in err
        with pytest.raises(CommunicationError, match="refusing to move blind|stream has failed"):
            drv.move_joints(_sweep_target(Q0), 0.3, 2.0, 10.0)
    finally:
        drv.close()


def test_server_drops_connections_mid_sweep_stop_over_new_connection(ur, stall_probe):
    fake, options = ur
    drv = _driver(options)
    got = []
    try:
        drv.start_stream(got.append)
        timer_t = []

        def drop():
            timer_t.append(time.monotonic())
            fake.inject_fault("drop_connections")

        import threading
        threading.Timer(0.5, drop).start()
        with pytest.raises(SupervisionTrip) as info:
            drv.move_joints(_sweep_target(Q0, deg=40), 0.3, 2.0, 10.0)
        report = info.value.stop_report
        assert report.via == "new connection" and report.acknowledged
        stop = fake.first_event_after("stop", timer_t[0])
        assert stop is not None
        assert_latency_within(stop.t - timer_t[0], 0.5, stall_probe, timer_t[0], "stop")
        assert not any(e.kind == "move" and e.t > timer_t[0] for e in fake.events)
        # the samples up to the drop are kept: they ran while the arm moved
        before = [s for s in got if s.t_recv < timer_t[0]]
        assert len(before) > 5 and before[-1].q[1] > Q0[1] + 0.01
        deadline = time.monotonic() + 2.0
        while fake.robot.snapshot().moving and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not fake.robot.snapshot().moving
    finally:
        drv.close()


def test_no_reply_times_out_and_says_the_stop_was_not_heard(ur, stall_probe):
    fake, options = ur
    drv = _driver(options, Supervision(max_stream_gap_s=0.3, stop_ack_timeout_s=0.6))
    try:
        import threading
        fault_t = []
        threading.Timer(0.4, lambda: (fault_t.append(time.monotonic()), fake.inject_fault("no_reply"))).start()
        with pytest.raises((SupervisionTrip, MotionAbortedError)) as info:
            drv.move_joints(_sweep_target(Q0, deg=40), 0.3, 2.0, 10.0)
        report = drv.last_stop_report
        assert report is not None and not report.acknowledged and report.stop_sent_t is not None
        assert "NOT acknowledged" in str(info.value)
        # the device swallowed the replies, not the requests: the stop reached it all the same
        stop = fake.first_event_after("stop", fault_t[0])
        assert stop is not None
        assert_latency_within(stop.t - fault_t[0], 0.5, stall_probe, fault_t[0], "stop")
    finally:
        fake.clear_faults()
        drv.close()


def test_slow_replies_are_gaps_not_samples(ur):
    fake, options = ur
    drv = _driver(options, Supervision(max_stream_gap_s=0.3, stop_ack_timeout_s=0.5))
    try:
        fake.inject_fault("slow_reply", delay_s=0.5)  # beyond the 0.25 s request timeout
        with pytest.raises(SupervisionTrip, match="stalled|no reply"):
            drv.move_joints(_sweep_target(Q0), 0.3, 2.0, 10.0)
    finally:
        fake.clear_faults()
        drv.close()


def test_protective_stop_and_pendant_control_refuse_motion(ur):
    fake, options = ur
    drv = _driver(options)
    try:
        import threading
        threading.Timer(0.3, fake.inject_fault, args=("protective_stop",)).start()
        with pytest.raises(MotionAbortedError, match="protective stop"):
            drv.move_joints(_sweep_target(Q0, deg=40), 0.3, 2.0, 10.0)
        st = drv.state()
        assert not st.motion_allowed and st.protective_stop and "clear it at the pendant" in st.reason
        fake.clear_faults()
        fake.inject_fault("leave_remote")
        time.sleep(0.05)  # the next refresh of the registers
        st = drv.state()
        assert not st.motion_allowed and "robot mode is" in st.reason
        with pytest.raises(MotionAbortedError):
            drv.move_joints(_sweep_target(Q0), 0.3, 2.0, 10.0)
    finally:
        drv.close()


def test_program_not_running_is_named():
    fake, options = _start(heartbeat_timeout_s=0.2, ack_timeout_s=0.4)
    drv = _driver(options)
    try:
        fake.stop_program()
        st = drv.state()
        assert not st.motion_allowed and "handshake program is not running" in st.reason
        with pytest.raises(MotionAbortedError, match="did not take move|heartbeat"):
            drv.move_joints(_sweep_target(Q0), 0.3, 2.0, 10.0)
        assert not fake.robot.snapshot().moving
        fake.restart_program()  # the command written before is not taken on restart
        time.sleep(0.1)
        assert not fake.robot.snapshot().moving
    finally:
        drv.close()
        fake.close()


def test_payload_write_and_read_back_and_inputs(ur):
    fake, options = ur
    drv = _driver(options)
    try:
        drv.write_payload(PayloadSetting(2.345, (0.03, -0.02, 0.061)))
        back = drv.read_payload()
        assert back.mass_kg == pytest.approx(2.345) and np.allclose(back.cog_m, (0.03, -0.02, 0.061), atol=1e-4)
        assert fake.payload_setting[0] == pytest.approx(2.345)
        assert [e.kind for e in fake.events][-1] == "payload"
        fake.set_digital_inputs(0b1000_0000)
        time.sleep(0.05)  # the next refresh of the registers
        assert drv.read_digital_input(7) and not drv.read_digital_input(6)
        with pytest.raises(UnsupportedCapability):
            drv.read_digital_input(16)
        assert drv.read_trigger() == 0
        fake.set_tool_change(1)
        time.sleep(0.05)
        assert drv.read_trigger() == 1
        fake.set_tool_change(12)  # a PLC writing the tool's number
        time.sleep(0.05)
        assert drv.read_trigger() == 12
    finally:
        drv.close()


def test_tcp_offset_is_taken_out_of_the_pose(ur):
    fake, options = ur
    fake.set_tcp_offset([0.0, 0.0, 0.15], [0.0, 0.0, 0.5])
    drv = _driver(options)
    try:
        time.sleep(0.05)
        s = drv.wait_sample(1.0)
        T = Kinematics(ur5e_spec().dh).flange(np.asarray(s.q))
        pose = drv.flange_pose()
        assert np.allclose(pose.position_m, T[:3, 3], atol=2e-3)  # offset registers in whole mm
        assert np.allclose(np.asarray(pose.rotation), T[:3, :3], atol=5e-3)
    finally:
        drv.close()


def test_a_target_the_map_cannot_carry_sends_nothing():
    fake, options = _start("igus_rebel", map={"joint_efforts": {"type": "int16"}})  # int16 × 0.1° targets
    try:
        drv = _driver(options)
        try:
            t0 = time.monotonic()
            with pytest.raises(MotionAbortedError, match=r"cmd_target\[0\] = .* outside -32768..32767"):
                drv.move_joints(np.radians([4000, 0, 0, 0, 0, 0]), 0.3, 2.0, 10.0)
            assert fake.first_event_after("move", t0) is None
        finally:
            drv.close()
    finally:
        fake.close()


def test_connect_failure_names_the_endpoint():
    options = parse_modbus_options({"type": "modbus", "host": "127.0.0.1", "port": 1, "preset": "generic_float32",
                                    "timeout_s": 0.2})
    drv = ModbusDriver(options, LIMITS)
    with pytest.raises(CommunicationError, match=r"127\.0\.0\.1:1 \(Modbus TCP, unit 1\)"):
        drv.connect()


def test_watch_fires_on_the_tool_change_register(ur, tmp_path):
    import yaml

    from conftest import ROOT, tweak
    from payload_agent.configuration.config import parse_config
    from payload_agent.session.watch import watch

    fake, options = ur
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e-modbus.yaml").read_text())
    data = tweak(data, "watch", {"trigger": {"type": "register"}, "poll_interval_s": 0.02})
    config = parse_config(data, source="test")
    runs, lines = [], []

    def run_once():
        runs.append(time.monotonic())
        return 0

    import threading
    reads = []

    def factory():  # a driver whose trigger reads the test can see: the edge must come after a low read
        drv = ModbusDriver(options, LIMITS, RELAXED)
        read = drv.read_trigger
        drv.read_trigger = lambda: reads.append(read()) or reads[-1]
        return drv

    def raise_after_a_low_read():
        deadline = time.monotonic() + 30
        while not reads and time.monotonic() < deadline:
            time.sleep(0.01)
        fake.set_tool_change(1)

    threading.Thread(target=raise_after_a_low_read, daemon=True).start()
    give_up = threading.Event()
    timer = threading.Timer(60, give_up.set)  # never hang the suite: watch ends with no run, and the test fails
    timer.start()
    try:
        code = watch(config, run_once, driver_factory=factory, out=lines.append, max_runs=1, stop_event=give_up)
    finally:
        timer.cancel()
    assert reads and reads[0] == 0
    assert code == 0 and len(runs) == 1
    assert any("the trigger register went high" in line for line in lines)


def test_watch_takes_the_tool_number_from_the_register(ur):
    """``tool_from_value``: the PLC writes the new tool's number; 7, then 9 over it without clearing: two changes,
    each run given the number (which the tool library resolves)."""
    import threading

    import yaml

    from conftest import ROOT, tweak
    from payload_agent.configuration.config import parse_config
    from payload_agent.session.watch import watch

    fake, options = ur
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e-modbus.yaml").read_text())
    data = tweak(data, "watch", {"trigger": {"type": "register", "tool_from_value": True}, "poll_interval_s": 0.02})
    config = parse_config(data, source="test")
    tools, lines, reads = [], [], []
    reference_after_run = threading.Event()
    marks = []

    def factory():
        drv = ModbusDriver(options, LIMITS, RELAXED)
        read = drv.read_trigger

        def counted():
            reads.append(read())
            if marks and len(reads) > marks[0] and reads[-1] == 7:
                reference_after_run.set()  # read 7 again after run 1: the reference for the next change
            return reads[-1]
        drv.read_trigger = counted
        return drv

    def run_tool(name):
        tools.append(name)
        marks.append(len(reads))
        return 0

    def plc():
        deadline = time.monotonic() + 30
        while 0 not in reads and time.monotonic() < deadline:
            time.sleep(0.01)
        fake.set_tool_change(7)
        if reference_after_run.wait(30):
            fake.set_tool_change(9)  # the next tool's number over the last one, without clearing

    threading.Thread(target=plc, daemon=True).start()
    give_up = threading.Event()
    timer = threading.Timer(60, give_up.set)
    timer.start()
    try:
        code = watch(config, lambda: 1, driver_factory=factory, out=lines.append, max_runs=2, stop_event=give_up,
                     run_tool=run_tool)
    finally:
        timer.cancel()
    assert code == 0 and tools == ["7", "9"], (tools, lines)
    assert reads[0] == 0
    assert any("reads tool number 7" in line for line in lines)


def test_a_status_flag_that_is_neither_0_nor_1_is_a_garbled_reply_not_an_emergency_stop(ur):
    """A safety flag register that reads 1311 (a late reply of another block once did) must not be reported as an
    emergency stop the operator is then sent to release: the status is unknown and the driver says so."""
    fake, options = ur
    drv = _driver(options)
    try:
        fake.inject_fault("stall_stream")  # the device image stops refreshing: our value stays
        address = fake.map["emergency_stop"].address
        fake.store.set_many([("holding", address, [1311])])
        with pytest.raises(CommunicationError, match=f"1311 for emergency_stop \\(holding {address}\\).*neither 0 nor 1"):
            drv.state()
    finally:
        drv.close()
