"""The driver contract, the same for every family: each scenario runs against every built-in driver and its
simulated controller, through the real client library and protocol on loopback.

A new family adds one line to FAMILIES (its sim YAML's name in benchmarks.fault_matrix.SIM_CONFIGS, an
option its parser must refuse naming the key, and the modules of its client library). Protocol quirks stay
in the family's own test file.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from benchmarks.fault_matrix import load_sim_config
from payload_agent.drivers.registry import driver_class, make_driver, parse_driver_options, simulator_class
from payload_agent.errors import (CommunicationError, ConfigError, MotionAbortedError, MotionNotFinished, MotionStopped,
                                  PayloadAgentError, SafetyError, SupervisionTrip)
from payload_agent.session.connection import motion_limits, supervision
from payload_agent.session.simulation import SimulatedCell

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Family:
    name: str
    bad_option: tuple[dict, str]  # a driver section the parser refuses, and the key its error names
    client_modules: tuple[str, ...]  # what parsing a robot YAML must not import
    stop_words: dict[str, str]  # how the abort names a controller-side stop (regex), by fault


FAMILIES = [
    Family("elite_ec", ({"host": "h", "rpc_port": 70000}, "driver.rpc_port"), (),
           {"emergency_stop": "emergency stop", "protective_stop": "collision"}),
    Family("ur_rtde", ({"host": "h", "target_tolerance_deg": -1}, "driver.target_tolerance_deg"),
           ("rtde_receive", "rtde_control"), {"emergency_stop": "emergency stop", "protective_stop": "protective stop"}),
    Family("modbus", ({"host": "h", "preset": "generic_float32", "timeout_s": 0}, "driver.timeout_s"),
           ("pymodbus",), {"emergency_stop": "emergency stop", "protective_stop": "protective stop"}),
    Family("canopen", ({"interface": "virtual", "channel": "x", "node_ids": [1, 2, 3, 4, 5, 5],
                        "counts_per_rad": [1e5] * 6}, "driver.node_ids[5]"), ("canopen",),
           {"emergency_stop": "0x3220", "protective_stop": "0x8611"}),  # the drives' EMCY codes
]
FAMILY_IDS = [f.name for f in FAMILIES]


# Module-scoped, so that pytest runs the file family by family (it orders tests to keep a module-scoped parameter
# for as long as it can): a family's simulated controllers then idle (500 Hz clocks in their own processes, about
# 0.08-0.14 s of CPU a second each) only while its own tests run, not through the whole file (``idle_cells``).
@pytest.fixture(scope="module", params=FAMILIES, ids=FAMILY_IDS)
def family(request) -> Family:
    return request.param


class _Watched:
    """The controller a test drives, noting whether the test injected a fault (every other use passes through)."""

    def __init__(self, ctrl):
        self._ctrl, self.faulted = ctrl, False

    def inject_fault(self, *args, **kwargs):
        self.faulted = True
        return self._ctrl.inject_fault(*args, **kwargs)

    def __getattr__(self, name):
        return getattr(self._ctrl, name)


@pytest.fixture(scope="module")
def idle_cells():
    """Simulated controllers a test left as a fresh one is, by family: the next test of the family takes it
    instead of starting a controller (a process of its own for three families: about 1 s of wall and 0.5 s of
    CPU each). A test that injected a fault, or after which the arm still moves or the controller does not
    allow motion, closes its controller: the next test gets a new one. Every test connects a new driver. The
    first test of another family closes the ones kept (``family`` runs the file family by family)."""
    cells: dict[str, tuple[SimulatedCell, object]] = {}
    yield cells
    for cell, _ in cells.values():
        cell.close()


def _left_clean(drv, ctrl: _Watched) -> bool:
    """Whether the controller is as a fresh one for the next test: no fault injected, the arm at rest with no
    safety stop, and the controller allowing motion (asked through the test's driver)."""
    if ctrl.faulted:
        return False
    try:
        snap = ctrl.robot.snapshot()
        st = drv.state()
    except Exception:
        return False
    return (not snap.moving and not snap.estop and not snap.protective_stop and st.motion_allowed
            and not st.estop and not st.protective_stop and not drv.motion_commanded)


@pytest.fixture
def rig(family, idle_cells, tmp_path):
    """A simulated controller of the family (one a test left clean, or a new one) and a new connected driver
    with a fresh sample."""
    for other in [name for name in idle_cells if name != family.name]:  # the file runs family by family
        idle_cells.pop(other)[0].close()
    cell, config = idle_cells.pop(family.name, (None, None))
    if cell is None:
        # the CANopen drives' watch of the agent's heartbeat keeps the sim config's allowance: at the driver's
        # real 150 ms a CI machine with both cores busy tripped it before a move (EMCY 0x8130, session 24's CI);
        # the fault matrix keeps 150 ms, and tests/test_canopen_driver tests the watch itself
        config = load_sim_config(family.name, tmp_path, strict_heartbeat=False)
        # the stream's gap limit 1 s instead of the matrix's 0.5 s: a busy CI machine starved a driver's stream for
        # 605 ms (test_ur_driver, session 24); the stalled-stream test's stall never ends, so it still trips
        config = dataclasses.replace(config, safety=dataclasses.replace(config.safety, max_stream_gap_s=1.0))
        cell = SimulatedCell(config).start()
    ctrl = _Watched(cell.controller)
    drv = make_driver(cell.options, motion_limits(config), supervision(config))
    clean = False
    try:
        drv.connect()
        drv.wait_sample(5.0)
        yield drv, ctrl, config
        clean = _left_clean(drv, ctrl)
    finally:
        drv.close()
        if clean:
            idle_cells[family.name] = (cell, config)
        else:
            cell.close()


def _target(drv, deg: float = 20.0) -> np.ndarray:
    """A move of joints 2 and 3 long enough to be caught mid-way."""
    return np.asarray(drv.latest_sample.q) + np.radians([0.0, deg, -deg, 0.0, 0.0, 0.0])


def _when_moving(ctrl, action, *args) -> threading.Thread:
    """Run ``action(*args)`` once the simulated arm moves (from a thread; the move blocks the test)."""
    def run():
        deadline = time.monotonic() + 10.0
        while not ctrl.robot.snapshot().moving and time.monotonic() < deadline:
            time.sleep(0.002)
        action(*args)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def _comes_to_rest(ctrl, within_s: float = 5.0) -> bool:
    deadline = time.monotonic() + within_s
    while ctrl.robot.snapshot().moving:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _slow(drv) -> tuple[float, float]:
    return 0.25 * drv.limits.max_joint_speed_rad_s, 0.5 * drv.limits.max_joint_accel_rad_s2


# -- without a controller ---------------------------------------------------------------------------------

def test_registry_names_the_driver_and_its_simulator(family):
    cls = driver_class(family.name)
    assert cls.name == family.name and simulator_class(family.name).faults


def test_bad_options_name_the_key(family):
    data, key = family.bad_option
    with pytest.raises(ConfigError) as err:
        parse_driver_options({"type": family.name, **data})
    assert err.value.key_path == key


def test_parsing_a_robot_yaml_imports_no_client_library(family):
    config = {"elite_ec": "ec66", "ur_rtde": "ur5e", "modbus": "ur5e-modbus", "canopen": "canopen-arm"}[family.name]
    code = (f"import sys\nfrom payload_agent.configuration.config import load_config\n"
            f"c = load_config({str(ROOT / 'configs' / (config + '.yaml'))!r})\n"
            f"assert c.driver_type == {family.name!r}\n"
            f"print(sorted(m for m in {family.client_modules!r} if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_stop_never_raises_and_sends_nothing_unconnected(family, tmp_path):
    config = load_sim_config(family.name, tmp_path)
    drv = make_driver(config.driver_options, motion_limits(config), supervision(config))
    assert drv.stop() is False and not drv.motion_commanded
    drv.close()


# -- against the simulated controller -----------------------------------------------------------------------

def test_identify_and_state(rig):
    drv, ctrl, config = rig
    info = drv.identify()
    assert info.vendor and info.model
    st = drv.state()
    assert st.motion_allowed and not st.estop and not st.protective_stop, st
    drv.check_effort_unit(config.effort.unit)  # the robot YAML's unit is the driver's


def test_move_completes_at_target_and_a_later_stop_sends_nothing(rig):
    drv, ctrl, _ = rig
    target = _target(drv, 5.0)
    t0 = time.monotonic()
    # first a request beyond the robot's speed limit: refused by the base, before anything goes out
    with pytest.raises(SafetyError, match="robot.max_joint_speed_deg_s"):
        drv.move_joints(target, 1.5 * drv.limits.max_joint_speed_rad_s, drv.limits.max_joint_accel_rad_s2, 20.0)
    assert ctrl.first_event_after("move", t0) is None and not drv.motion_commanded
    drv.move_joints(target, 0.5 * drv.limits.max_joint_speed_rad_s, drv.limits.max_joint_accel_rad_s2, 20.0)
    assert np.max(np.abs(np.asarray(drv.wait_sample(2.0, after=time.monotonic()).q) - target)) \
        <= drv.target_tolerance_rad
    assert ctrl.first_event_after("move", t0) is not None
    assert not drv.motion_commanded  # the controller reported our move finished: nothing of ours runs
    assert drv.stop() is False and ctrl.first_event_after("stop", t0) is None


@pytest.mark.parametrize("fault", ["emergency_stop", "protective_stop"])
def test_a_controller_side_stop_mid_move_aborts_and_is_named(rig, family, fault):
    drv, ctrl, _ = rig
    target = _target(drv)
    t0 = time.monotonic()
    th = _when_moving(ctrl, ctrl.inject_fault, fault)
    with pytest.raises(MotionAbortedError, match=family.stop_words[fault]):
        drv.move_joints(target, *_slow(drv), 30.0)
    th.join()
    assert _comes_to_rest(ctrl)
    assert np.max(np.abs(ctrl.robot.snapshot().q - target)) > 0.02  # it ended the move, not its timeout
    assert ctrl.first_event_after("stop", t0) is not None  # and stopped it (the rest of the arm, the program)
    assert not drv.state().motion_allowed


def test_a_timeout_stops_the_arm(rig):
    drv, ctrl, _ = rig
    target = _target(drv)
    t0 = time.monotonic()
    with pytest.raises(MotionAbortedError, match="did not finish"):
        drv.move_joints(target, *_slow(drv), 0.3)
    assert ctrl.first_event_after("stop", t0) is not None and _comes_to_rest(ctrl)


def test_a_move_never_reported_finished_is_stopped(rig):
    drv, ctrl, _ = rig
    ctrl.inject_fault("never_finish")
    t0 = time.monotonic()
    with pytest.raises(MotionNotFinished, match="did not report the move finished"):  # the arm stood at the
        drv.move_joints(_target(drv, 3.0), 0.5 * drv.limits.max_joint_speed_rad_s,  # target: the supervision's
                        drv.limits.max_joint_accel_rad_s2, 20.0)  # finish grace, long before the move's timeout
    assert ctrl.first_event_after("stop", t0) is not None


def test_the_finish_grace_is_the_yamls_gap_limit_where_that_allows_a_later_controller(tmp_path):
    """A YAML that allows the stream longer silences (a busy host) allows the controller's "finished" as late."""
    config = load_sim_config("elite_ec", tmp_path)
    for gap_s, grace_s in ((1.0, 1.0), (0.1, 0.5)):
        safety = dataclasses.replace(config.safety, max_stream_gap_s=gap_s)
        assert supervision(dataclasses.replace(config, safety=safety)).finish_grace_s == grace_s


def test_our_stop_from_another_thread_ends_our_move_and_the_next_one_runs(rig):
    drv, ctrl, _ = rig
    start = np.asarray(drv.latest_sample.q)
    th = _when_moving(ctrl, drv.stop)
    with pytest.raises(MotionStopped, match="stopped on request"):
        drv.move_joints(_target(drv), *_slow(drv), 30.0)
    th.join()
    assert _comes_to_rest(ctrl) and not drv.motion_commanded  # the controller acknowledged our stop
    drv.move_joints(start, 0.5 * drv.limits.max_joint_speed_rad_s, drv.limits.max_joint_accel_rad_s2, 20.0)


def test_a_stalled_stream_trips_and_stops_the_arm(rig):
    drv, ctrl, _ = rig
    t0 = time.monotonic()
    th = _when_moving(ctrl, ctrl.inject_fault, "stall_stream")
    with pytest.raises(SupervisionTrip, match="stalled") as err:
        drv.move_joints(_target(drv), *_slow(drv), 30.0)
    th.join()
    report = err.value.stop_report  # the command channel still works: the stop goes there
    assert report is not None and report.via == "command channel" and report.acknowledged, report
    assert ctrl.first_event_after("stop", t0) is not None and _comes_to_rest(ctrl)


def test_lost_connections_stop_the_arm_over_a_fresh_connection(rig, family):
    drv, ctrl, _ = rig
    t0 = time.monotonic()
    th = _when_moving(ctrl, ctrl.inject_fault, "drop_connections")
    speed, accel = _slow(drv)
    with pytest.raises(PayloadAgentError) as err:  # 30° at half the usual speed: the drop comes mid-move even
        drv.move_joints(_target(drv, 30.0), 0.5 * speed, accel, 30.0)  # when a loaded host delays the injection
    th.join()
    assert isinstance(err.value, (SupervisionTrip, CommunicationError, MotionAbortedError))
    report = getattr(err.value, "stop_report", None) or drv.last_stop_report
    # Modbus TCP's bus opens its command connection anew, in place, after a request the dropped connection left
    # unanswered (drivers/modbus/bus.py, _reconnect): by the trip its command channel may already be that fresh
    # connection (seen once in CI: stop 3 ms after the stall, acknowledged)
    assert report is not None, err.value
    if family.name == "modbus" and report.via == "command channel":
        assert report.acknowledged, report
    else:
        assert report.via == "new connection", report
    assert _comes_to_rest(ctrl)
    assert ctrl.first_event_after("stop", t0) is not None
