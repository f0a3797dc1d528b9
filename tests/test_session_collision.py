"""A session refused while another moves the arm leaves that motion alone (issue 19).

Per driver, over the real protocol: session A (a bare driver) commands a long, slow move; session B, a
whole `run` against the same controller, is refused because the robot is moving. B must exit with its
documented code and send nothing that stops A: the simulated controller's command log shows no stop
while B ran, and A's move is still under way afterwards (A then stops its own move, as it may).
"""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from payload_agent.configuration.config import load_config
from payload_agent.drivers.registry import make_driver
from payload_agent.drivers.settings import Supervision
from payload_agent.errors import MotionAbortedError, RobotNotReadyError
from payload_agent.session.connection import build_driver, motion_limits, simulated_cell
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

from conftest import ROOT

ROBOTS = ["sim-ec66", "sim-ur5e", "sim-ur5e-modbus", "sim-canopen-arm"]


def _wait(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def _patient_driver(config, options):
    """Session A, the other program whose motion B must leave alone: it shares this process (and the GIL) with
    the simulated controller and with B's whole session, whose planning can starve A's threads for seconds on a
    loaded host. A real other program has its own process, so A waits long for replies and samples here;
    B's supervision, the thing under test, keeps the YAML's."""
    patient = {k: v for k, v in (("reply_timeout_s", 30.0), ("timeout_s", 10.0)) if hasattr(options, k)}
    return make_driver(dataclasses.replace(options, **patient), motion_limits(config),
                       Supervision(max_stream_gap_s=10.0, stop_ack_timeout_s=2.0, max_reply_wait_s=30.0))


@pytest.mark.parametrize("robot", ROBOTS)
def test_a_refused_session_never_stops_the_motion_of_another(robot, tmp_path):
    config = load_config(ROOT / "configs" / f"{robot}.yaml")
    with simulated_cell(config) as cell:
        a = _patient_driver(config, cell.options)
        a.connect()
        try:
            a.start_stream(lambda sample: None)
            q0 = np.asarray(a.wait_sample(5.0).q, dtype=float)
            target = q0.copy()
            target[0] += np.radians(60.0)  # the base joint: far, slow, clear of every limit
            speed = 0.02 * config.robot.max_joint_speed_rad_s
            outcome: dict[str, BaseException | None] = {}

            def move() -> None:
                try:
                    a.move_joints(target, speed, config.robot.max_joint_accel_rad_s2 * 0.2, timeout_s=600.0)
                    outcome["a"] = None
                except BaseException as exc:  # noqa: BLE001 - reported below
                    outcome["a"] = exc

            mover = threading.Thread(target=move, daemon=True)
            mover.start()
            _wait(lambda: abs(a.latest_sample.q[0] - q0[0]) > np.radians(0.5), 60.0, "session A's move to start")

            t_b = time.monotonic()
            with pytest.raises(RobotNotReadyError) as refused:
                run_identification(config, RunOptions(assume_yes=True, report=False),
                                           OperatorUI(out=lambda *_: None),
                                           SimulatedCellUse(cell=cell))
            t_b_end = time.monotonic()
            assert refused.value.exit_code == 3
            assert any(w in str(refused.value) for w in ("moving", "running a motion", "another CANopen master"))
            stops = [e for e in cell.controller.events if e.kind == "stop" and t_b <= e.t <= t_b_end]
            assert stops == [], f"the refused session sent a stop: {stops}"
            assert mover.is_alive() and "a" not in outcome, "session A's move ended while B was refused"
            q_then = a.latest_sample.q[0]
            _wait(lambda: abs(a.latest_sample.q[0] - q_then) > np.radians(0.2), 60.0, "session A's move to go on")
            assert a.motion_commanded
        finally:
            a.stop()  # session A's own move: A may stop it
            mover.join(60.0)
            a.close()
    assert not mover.is_alive()
    assert outcome.get("a") is None or isinstance(outcome["a"], MotionAbortedError), outcome


def test_a_driver_that_commanded_nothing_sends_no_stop():
    """stop() on a connected driver that never moved sends nothing; after its own move finished, neither."""
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    with simulated_cell(config) as cell:
        driver = build_driver(config, cell.options)
        driver.connect()
        try:
            driver.start_stream(lambda sample: None)
            assert driver.stop() is False and not driver.motion_commanded
            q = np.asarray(driver.wait_sample(5.0).q, dtype=float)
            driver.move_joints(q + np.radians([2.0, 0, 0, 0, 0, 0]), 0.5, 2.0, timeout_s=60.0)
            assert not driver.motion_commanded  # finished at its target: nothing of ours runs
            assert driver.stop() is False
            assert [e for e in cell.controller.events if e.kind == "stop"] == []
        finally:
            driver.close()


def test_the_modbus_robot_keeps_its_identity_on_a_new_port():
    """A register map reports no serial: the YAML's driver.serial is the robot's, never host:port, so a stored
    baseline survives the controller (here the simulated one) coming up on another port; another serial is
    still another robot."""
    import dataclasses

    from payload_agent.motion.planner import make_plan
    from payload_agent.session import baseline as baselines
    from payload_agent.session.connection import identify_controller

    config = load_config(ROOT / "configs" / "sim-ur5e-modbus.yaml")
    plan = make_plan(config)
    infos, endpoints = [], []
    for _ in range(2):  # two sessions, each simulated server on an ephemeral port of its own
        with simulated_cell(config) as cell:
            driver = build_driver(config, cell.options)
            driver.connect()
            try:
                infos.append(identify_controller(driver))
                endpoints.append(driver.describe_endpoint())
            finally:
                driver.close()
    assert endpoints[0] != endpoints[1]
    assert infos[0] == infos[1] and infos[0].serial == "SIM-UR5E-0001"
    stored, now = (baselines.describe_for(config, plan, info, source_run=ROOT) for info in infos)
    assert baselines.mismatches(stored, now, max_age_days=7) == []
    other = baselines.describe_for(config, plan, dataclasses.replace(infos[1], serial="SIM-UR5E-0002"), ROOT)
    assert any("serial changed" in r for r in baselines.mismatches(stored, other, max_age_days=7))


def test_a_declared_serial_the_controller_contradicts_is_refused():
    import dataclasses

    from payload_agent.errors import ConfigError
    from payload_agent.session.connection import identify_controller

    config = load_config(ROOT / "configs" / "sim-ur5e.yaml")
    with simulated_cell(config) as cell:
        driver = build_driver(config, dataclasses.replace(cell.options, serial="20990000000"))
        driver.connect()
        try:
            reported = driver.identify().serial
            assert reported  # the UR dashboard reports its serial number
            with pytest.raises(ConfigError, match="driver.serial") as wrong:
                identify_controller(driver)
            assert reported in str(wrong.value) and "20990000000" in str(wrong.value)
        finally:
            driver.close()
