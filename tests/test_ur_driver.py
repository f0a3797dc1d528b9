"""URRTDEDriver (real ur_rtde client) against the fake UR controller over real sockets."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur-rtde wheel not installed (CPython 3.11/3.12)")

from payload_agent.types import PayloadSetting  # noqa: E402
from payload_agent.drivers.registry import driver_class  # noqa: E402
from payload_agent.drivers.ur_rtde import URRTDEDriver  # noqa: E402
from payload_agent.errors import (  # noqa: E402
    CommunicationError,
    ConfigError,
    MotionAbortedError,
    RobotNotReadyError,
    SafetyError,
)
from payload_agent.fakes.physics import PayloadTruth  # noqa: E402
from payload_agent.fakes.ur_controller import DEFAULT_GAINS_NM_PER_A, FakeURController, pick_loopback_host  # noqa: E402

HOME = [0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0]


def make_driver(host: str, **extra) -> URRTDEDriver:
    return URRTDEDriver({"type": "ur_rtde", "host": host, **extra}, max_joint_speed_rad_s=3.0)


@pytest.fixture(scope="module")
def ur():
    with FakeURController(time_scale=1.0, current_noise_a=0.05) as fake:
        yield fake


@pytest.fixture(scope="module")
def drv(ur):
    d = make_driver(ur.host)
    d.connect()
    yield d
    d.close()


@pytest.fixture
def healthy(ur, drv):
    ur.reset_safety()
    yield drv
    ur.reset_safety()


# -- options -----------------------------------------------------------------------------------------

def test_registered_under_its_name():
    assert driver_class("ur_rtde") is URRTDEDriver
    assert URRTDEDriver.effort_unit == "A"


@pytest.mark.parametrize("options, key", [
    ({}, "driver.host"),
    ({"host": ""}, "driver.host"),
    ({"host": "10.0.0.1", "frequency_hz": 1000}, "driver.frequency_hz"),
    ({"host": "10.0.0.1", "frequency_hz": "fast"}, "driver.frequency_hz"),
    ({"host": "10.0.0.1", "upper_range_registers": "yes"}, "driver.upper_range_registers"),
    ({"host": "10.0.0.1", "target_tolerance_deg": -1}, "driver.target_tolerance_deg"),
    ({"host": "10.0.0.1", "rpc_port": 8055}, "driver.rpc_port"),
])
def test_bad_options_name_the_key(options, key):
    with pytest.raises(ConfigError) as err:
        URRTDEDriver({"type": "ur_rtde", **options}, max_joint_speed_rad_s=1.0)
    assert err.value.key_path == key


def test_unreachable_controller_is_a_communication_error():
    d = make_driver(pick_loopback_host(), connect_timeout_s=1.0)  # nothing listens there
    t0 = time.monotonic()
    with pytest.raises(CommunicationError, match="30004"):
        d.connect()
    assert time.monotonic() - t0 < 3.0


# -- against the fake --------------------------------------------------------------------------------

def test_identify_and_state(healthy):
    info = healthy.identify()
    assert (info.vendor, info.model, info.firmware) == ("Universal Robots", "UR5e", "5.11.1.108318")
    assert info.serial.isdigit()
    st = healthy.state()
    assert st.fault is None and st.mode == "remote" and st.servo_on


def test_stream_rate_500hz(healthy):
    """>= 95 % of the controller's 500 Hz packages reach the sink (time_scale 1, 2 s)."""
    samples = []
    healthy.start_stream(samples.append)
    try:
        time.sleep(2.0)
    finally:
        healthy.stop_stream()
    assert healthy.stream_error is None
    span = samples[-1].t_ctrl - samples[0].t_ctrl
    expected = span * 500.0 + 1
    rate = len(samples) / expected
    print(f"\nUR stream: {len(samples)} samples over {span:.3f} s of controller time = {100 * rate:.1f} % of 500 Hz")
    assert span > 1.9
    assert rate >= 0.95
    t = np.array([s.t_ctrl for s in samples])
    assert np.all(np.diff(t) > 0)  # de-duplicated, in order
    s = samples[-1]
    assert len(s.q) == 6 and len(s.effort) == 6


def test_effort_is_motor_current(ur, healthy):
    samples = []
    healthy.start_stream(samples.append)
    time.sleep(0.2)
    healthy.stop_stream()
    tau = ur.robot.snapshot().torque_nm  # standing still: the torque is constant
    effort = np.mean([s.effort for s in samples], axis=0)
    assert np.allclose(effort * np.asarray(DEFAULT_GAINS_NM_PER_A), tau, atol=0.1 * 10)


def test_move_reaches_target_and_stream_follows(healthy):
    target = [0.15, -1.45, 1.4, -1.55, -1.5, 0.1]
    samples = []
    healthy.start_stream(samples.append)
    try:
        healthy.move_joints(target, 1.0, 3.0, timeout_s=10.0)
        time.sleep(0.05)
    finally:
        healthy.stop_stream()
    assert np.allclose(samples[-1].q, target, atol=1e-6)
    assert np.allclose(healthy._recv.getActualQ(), target, atol=1e-6)
    qs = np.array([s.q for s in samples])
    assert np.ptp(qs[:, 0]) > 0.1  # the stream saw the move


def test_payload_write_and_read_back(ur, healthy):
    healthy.write_payload(PayloadSetting(1.75, (0.012, -0.004, 0.061)))
    got = healthy.read_payload()
    assert got.mass_kg == pytest.approx(1.75)
    assert got.cog_m == pytest.approx((0.012, -0.004, 0.061))
    assert ur.controller_payload[0] == pytest.approx(1.75)
    healthy.write_payload(PayloadSetting(0.0, (0.0, 0.0, 0.0)))  # all-zero cog is really written
    got = healthy.read_payload()
    assert got.mass_kg == 0.0 and got.cog_m == pytest.approx((0.0, 0.0, 0.0), abs=1e-8)


def test_protective_stop_mid_move_aborts(ur, healthy):
    healthy.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)
    timer = threading.Timer(0.4, ur.trigger_protective_stop)
    timer.start()
    t0 = time.monotonic()
    with pytest.raises(MotionAbortedError, match="protective stop"):
        healthy.move_joints([0.8, -1.2, 1.1, -1.3, -1.3, 0.5], 0.4, 1.0, timeout_s=20.0)
    assert time.monotonic() - t0 < 1.5
    timer.join()
    st = healthy.state()
    assert st.protective_stop and st.fault == "protective stop is active"
    with pytest.raises(RobotNotReadyError):
        healthy.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)
    # after the stop is cleared the driver re-uploads the control script and moves again
    ur.reset_safety()
    time.sleep(0.05)
    healthy.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)
    assert ur.programs_run.count("rtde_control") >= 2


def test_estop_mid_move_aborts(ur, healthy):
    timer = threading.Timer(0.3, ur.trigger_estop)
    timer.start()
    with pytest.raises(MotionAbortedError, match="emergency stop"):
        healthy.move_joints([0.5, -1.3, 1.3, -1.5, -1.4, 0.3], 0.4, 1.0, timeout_s=20.0)
    timer.join()
    st = healthy.state()
    assert st.estop and not st.servo_on
    ur.reset_safety()
    time.sleep(0.05)
    healthy.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)


def test_stop_from_another_thread_aborts_the_move(ur, healthy):
    timer = threading.Timer(0.3, healthy.stop)
    timer.start()
    with pytest.raises(MotionAbortedError, match="stopped on request"):
        healthy.move_joints([0.5, -1.3, 1.3, -1.5, -1.4, 0.3], 0.4, 1.0, timeout_s=20.0)
    timer.join()
    time.sleep(0.05)
    assert not ur.robot.snapshot().moving
    healthy.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)


def test_timeout_aborts_and_stops(ur, healthy):
    with pytest.raises(MotionAbortedError, match="did not finish"):
        healthy.move_joints([0.5, -1.3, 1.3, -1.5, -1.4, 0.3], 0.4, 1.0, timeout_s=0.3)
    time.sleep(0.05)
    assert not ur.robot.snapshot().moving
    healthy.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)


def test_speed_above_the_configured_cap_is_refused(healthy):
    with pytest.raises(SafetyError):
        healthy.move_joints(HOME, 5.0, 1.0, timeout_s=10.0)


def test_not_ready_when_remote_control_is_off():
    """Reading works in Local mode; the first command (which needs the control script) is refused."""
    with FakeURController(remote_control=False) as fake:
        d = make_driver(fake.host)
        try:
            d.connect()
            assert d.state().mode == "local" and d.read_digital_input(0) is False
            with pytest.raises(RobotNotReadyError, match="Remote Control"):
                d.move_joints(HOME, 1.0, 3.0, timeout_s=10.0)
            assert "rtde_control" not in fake.programs_run
        finally:
            d.close()


def test_connect_does_not_take_over_the_robot_program(ur):
    """connect() + reads upload nothing: a `watch` connection must not replace the robot's program."""
    before = ur.programs_run.count("rtde_control")
    d = make_driver(ur.host)
    try:
        d.connect()
        d.state()
        d.read_digital_input(3)
        assert ur.programs_run.count("rtde_control") == before
    finally:
        d.close()


def test_read_digital_input_follows_the_controller(ur, healthy):
    """Bit i of RTDE actual_digital_input_bits: DI0-7, CI0-7 (8-15), tool inputs TI0-1 (16-17)."""
    def settled(index, value):  # the receive interface sees the change from the next package on
        deadline = time.monotonic() + 2.0
        while healthy.read_digital_input(index) is not value:
            assert time.monotonic() < deadline, f"input {index} did not become {value}"
            time.sleep(0.005)

    try:
        for index in (0, 3, 7, 8, 15, 16, 17):
            assert healthy.read_digital_input(index) is False
            ur.set_digital_input(index, True)
            settled(index, True)
            others = [i for i in range(18) if i != index]
            assert not any(healthy.read_digital_input(i) for i in others)
            ur.set_digital_input(index, False)
            settled(index, False)
        assert ur.digital_in == 0
    finally:
        for index in range(18):
            ur.set_digital_input(index, False)
    for bad in (-1, 18, 64, True, 2.0):
        with pytest.raises(ValueError, match="0-7 standard"):
            healthy.read_digital_input(bad)


def test_joint_temperatures_follow_the_controller(ur, healthy):
    """RTDE joint_temperatures (in the driver's recipe) through ur-rtde's getJointTemperatures, in °C."""
    def settled(want):  # the receive interface sees the change from the next package on
        deadline = time.monotonic() + 2.0
        while True:
            got = healthy.joint_temperatures_c()
            if np.allclose(got, want, atol=1e-9, rtol=0):
                return got
            assert time.monotonic() < deadline, f"joint temperatures stayed {got}, expected {want}"
            time.sleep(0.005)

    first = healthy.joint_temperatures_c()
    assert len(first) == 6 and all(isinstance(v, float) and 25.0 <= v <= 45.0 for v in first)
    try:
        for want in ([36.5, 41.25, 39.0, 44.75, 43.5, 38.0], [30.0, 30.5, 31.0, 31.5, 32.0, 32.5]):
            ur.set_joint_temperatures(want)
            assert settled(want) == pytest.approx(want)
            assert ur.joint_temperatures == pytest.approx(want)  # without steady= they stay put
        ur.set_joint_temperatures([30.0] * 6, steady=[40.0] * 6)  # warming up: slow, monotonic
        time.sleep(0.5)
        a = healthy.joint_temperatures_c()
        time.sleep(0.5)
        b = healthy.joint_temperatures_c()
        assert all(30.0 < x < y < 30.1 for x, y in zip(a, b))  # tau 30 min: ~0.006 °C/s at 10 °C below
        with pytest.raises(ValueError, match="6 numbers"):
            ur.set_joint_temperatures([30.0] * 5)
    finally:
        ur.set_joint_temperatures(first)


def test_long_move_fast_sim_with_payload():
    """A long move at time_scale 10: the move still ends on target, the tool shows in the current."""
    with FakeURController(time_scale=10.0, payload=PayloadTruth(3.0, (0.0, 0.0, 0.08))) as fake:
        d = make_driver(fake.host)
        try:
            d.connect()
            target = [1.2, -1.0, 1.0, -1.2, -1.0, 1.0]
            samples = []
            d.start_stream(samples.append)
            d.move_joints(target, 0.5, 1.0, timeout_s=30.0)  # ~2.5 s simulated, ~0.3 s wall
            d.stop_stream()
            assert np.allclose(d._recv.getActualQ(), target, atol=1e-6)
            # the tool's weight is in the shoulder current: |current| well above the empty arm's noise
            assert len(samples) > 10 and abs(samples[-1].effort[1]) > 1.0
        finally:
            d.close()


def test_lost_connection_ends_the_stream_with_an_error():
    fake = FakeURController().start()
    d = make_driver(fake.host)
    try:
        d.connect()
        samples = []
        d.start_stream(samples.append)
        time.sleep(0.2)
        fake.close()
        deadline = time.monotonic() + 5.0
        while d.stream_error is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert isinstance(d.stream_error, CommunicationError)
        assert samples
    finally:
        d.close()
        fake.close()


def test_missing_wheel_fails_only_this_driver(monkeypatch):
    """Without the ur-rtde wheel (Python 3.13+) the UR driver names the problem; Elite still loads."""
    import sys

    from payload_agent.drivers import registry

    monkeypatch.setitem(sys.modules, "rtde_control", None)  # "import rtde_control" now raises ImportError
    monkeypatch.delitem(sys.modules, "payload_agent.drivers.ur_rtde")
    monkeypatch.setattr(registry, "_REGISTERED", {})
    with pytest.raises(ConfigError) as err:
        driver_class("ur_rtde")
    assert err.value.key_path == "driver.type"
    assert "ur-rtde" in str(err.value) and "CPython 3.11 and 3.12" in str(err.value)
    assert "payload-agent[ur]" in str(err.value)
    assert driver_class("elite_ec").name == "elite_ec"


def test_missing_wheel_is_a_config_error_naming_the_python_versions():
    import subprocess
    import sys

    code = ("import sys\nsys.modules['rtde_control'] = None\n"
            "from payload_agent.errors import ConfigError\n"
            "try:\n    import payload_agent.drivers.ur_rtde\nexcept ConfigError as e:\n"
            "    print(e.key_path, 'CPython 3.11 and 3.12' in str(e))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "driver.type True", out.stderr
