"""`payload-agent verify` against the simulated EC66 over its real protocol: the library tool matches, a wrong
tool is found and named, the controller's payload setting is compared and written, the lock is respected."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from conftest import ROOT, cell_program_turns_joint_1, short_session, tweak
from payload_agent.cli import main
from payload_agent.configuration.config import parse_config
from payload_agent.errors import CommunicationError, RobotBusyError, ToolMismatchError
from payload_agent.recording.rundata import load_manifest
from payload_agent.recording.state import RobotState
from payload_agent.session.robot_lock import robot_lock
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification
from payload_agent.session.simulation import SimulatedCell
from payload_agent.session.verify import VerifyOptions, verify_tool, write_and_check
from payload_agent.tools import library
from payload_agent.tools.library import ToolEntry
from payload_agent.types import PayloadSetting

TRUTH = (2.0, (40.0, -25.0, 70.0))


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """A simulated EC66 whose baseline is stored and whose tool 'gripper' was identified by `run --tool`."""
    tmp = tmp_path_factory.mktemp("verify")
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "storage", {"runs_dir": str(tmp / "runs"), "state_dir": str(tmp / "state")})
    data = tweak(data, "simulation.payload", {"mass_kg": TRUTH[0], "cog_mm": list(TRUTH[1])})
    data = tweak(data, "simulation.time_scale", 8)  # lighter on a shared host than the YAML's 15
    # the module's ten verifies of the right tool share one stored baseline, each at α = 1 %. The simulation draws
    # its noise per motion (``simulation.noise_per_move``, the default), so every run here gets the same verdicts
    # under any load; the false-alarm rate itself is measured by benchmarks/verify_power.py
    data = tweak(data, "procedure.inertia", False)  # verify is about mass and CoM (the wrist part: test_wrist_*.py)
    data = short_session(data)  # the identifications' procedure is not the subject (conftest.short_session)
    cfg_path = tmp / "robot.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    config = parse_config(data, source=str(cfg_path))
    cell = SimulatedCell(config).start()
    try:
        run_identification(config, RunOptions(assume_yes=True, tool="gripper", report=False),
                                   OperatorUI(progress=False, out=lambda s: None),
                                   SimulatedCellUse(cell=cell))
        yield config, cell, cfg_path
    finally:
        cell.close()


def test_the_noise_estimate_does_not_depend_on_how_long_the_arm_stood_before_a_sweep():
    """A late move command leaves standing samples at the start of the sweep's file (a loaded host: 137 against
    the usual 5-25); the baseline's effort noise σ, the verify's variance and motion choice rest on it."""
    from payload_agent.recording.rundata import SweepData
    from payload_agent.tools import verify_stats as vs
    from payload_agent.types import SweepKey

    rng = np.random.default_rng(7)
    v, a, dt = 0.25, 1.2, 0.008
    t_ramp = v / a
    t_end = np.radians(55.0) / v + t_ramp

    def sweep(standing):
        t = np.arange(0.0, t_end, dt)
        s = np.where(t < t_ramp, 0.5 * a * t ** 2,
                     np.where(t > t_end - t_ramp, np.radians(55.0) - 0.5 * a * (t_end - t) ** 2, v * (t - 0.5 * t_ramp)))
        qdd = np.where(t < t_ramp, a, np.where(t > t_end - t_ramp, -a, 0.0))
        s = np.concatenate([np.zeros(standing), s])
        qdd = np.concatenate([np.zeros(standing), qdd])
        q = np.zeros((len(s), 6))
        q[:, 1] = -s
        tau = np.zeros((len(s), 6))
        tau[:, 1] = 40.0 * np.cos(q[:, 1]) + 8.0 * qdd  # gravity and the ramps' inertial torque
        effort = tau + rng.normal(0.0, 0.3, tau.shape)
        return {SweepKey("q", 2, "up", 10.0): SweepData(SweepKey("q", 2, "up", 10.0), np.arange(len(s)) * dt, q,
                                                        effort, "synthetic")}

    for standing in (5, 140):
        assert vs.noise_std(sweep(standing)).moving[1] == pytest.approx(0.3, rel=0.1), standing


def test_the_noise_of_a_sweeping_joint_and_of_a_standing_one_are_measured_apart():
    """The simulated UR5e's drives are 3-5× noisier turning than holding (its YAML's noise_nm and noise_rest_nm,
    from recordings): verify weighs a bin by the noise its joint had in that sweep, not one σ pooled over both
    (joint 2 pooled: 1.53 N·m against 2.11 sweeping and 0.46 standing)."""
    from payload_agent.fakes.arms import SPECS
    from payload_agent.fakes.base import sim_robot_kwargs
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.sim_robot import SimRobot
    from payload_agent.motion.planner import make_plan
    from payload_agent.tools import verify_stats as vs

    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text()))
    sim = config.simulation
    robot = SimRobot(SPECS[sim.arm](), tick_s=0.002, **{**sim_robot_kwargs(config), "seed": 5})
    baseline, _ = record_plan(robot, make_plan(config))
    assert {k.joint for k in baseline} == {2, 3}  # the plan sweeps joints 2 and 3; each stands in the other's
    noise = vs.noise_std(baseline)
    for j in (1, 2):
        assert noise.moving[j] == pytest.approx(sim.noise_nm[j], rel=0.1), j
        assert noise.standing[j] == pytest.approx(sim.noise_rest_nm[j], rel=0.1), j
    sweep3 = noise.for_sweep(2)  # a joint-3 sweep: joint 3 turns, joint 2 stands
    assert sweep3[2] == noise.moving[2] and sweep3[1] == noise.standing[1]


def _mount(mass, cog):
    def mount(cell):
        cell.change_tool(mass, cog)
        cell.mount_tool(True)
    return mount


def test_run_tool_stores_into_the_library_and_verify_matches(identified):
    config, cell, _ = identified
    db = library.tool_library_path(RobotState.for_config(config).root)
    entry = library.require(db, config.robot.name, "gripper")
    assert entry.source == "identified" and entry.run_dir and entry.history_id is not None
    assert abs(entry.mass_kg - TRUTH[0]) < 0.03 and entry.mass_std_kg > 0
    # the run's full covariance of [m, m·c] is stored with it (schema 2), and verify tests against it
    assert entry.covariance_theta_si is not None
    assert np.sqrt(entry.covariance_theta_si[0][0]) == pytest.approx(entry.mass_std_kg, rel=1e-6)
    lines = []
    outcome = verify_tool(config, VerifyOptions(tool="gripper", assume_yes=True, cell=cell, out=lines.append,
                                                detail=lambda s: None, mount=_mount(*TRUTH)))
    res = outcome.result
    assert res.matches and res.statistic <= res.threshold
    assert outcome.robot_time_s > 0 and abs(res.mass_kg - TRUTH[0]) < 0.05
    assert res.limits.mass_percent <= 5.0 and max(res.limits.cog_mm) <= 10.0  # the stated detection limit
    manifest = load_manifest(outcome.run_dir)
    assert manifest["mode"] == "verify" and manifest["status"] == "complete"
    assert all(s["status"] == "complete" for s in manifest["phases"]["loaded"]["sweeps"])
    assert json.loads((outcome.run_dir / "verify.json").read_text())["test"]["matches"] is True
    assert "MATCHES tool 'gripper'" in "\n".join(lines)


def test_wrong_tool_is_a_mismatch_naming_the_difference(identified):
    config, cell, _ = identified
    with pytest.raises(ToolMismatchError) as exc:
        verify_tool(config, VerifyOptions(tool="gripper", assume_yes=True, cell=cell, out=lambda s: None,
                                          detail=lambda s: None, mount=_mount(2.4, TRUTH[1])))
    err = exc.value
    assert err.exit_code == 7 and "DOES NOT MATCH tool 'gripper'" in str(err)
    assert err.outcome.result.mass_diff_kg == pytest.approx(0.4, abs=0.1)  # what differs, and by how much
    assert "Nothing was written" in str(err)


def test_cli_verify_apply_writes_the_library_payload_and_exit_codes(identified, capsys):
    config, cell, cfg_path = identified
    # the controller's setting differs from the library: verify --apply writes it and reads it back
    cell.change_tool(*TRUTH)
    assert main(["verify", "--robot", str(cfg_path), "--tool", "nope", "--yes"]) == 5  # unknown tool: no motion
    assert "no tool 'nope'" in capsys.readouterr().err
    lock_state = RobotState.for_config(config)
    with robot_lock(lock_state, "test holds it", config.robot.name):
        with pytest.raises(RobotBusyError):
            verify_tool(config, VerifyOptions(tool="gripper", assume_yes=True, cell=cell, out=lambda s: None))
    moves_before = cell.robot.snapshot().move_id
    outcome = verify_tool(config, VerifyOptions(tool="gripper", assume_yes=True, apply=True, cell=cell,
                                                out=lambda s: None, detail=lambda s: None, mount=_mount(*TRUTH)))
    assert cell.robot.snapshot().move_id > moves_before
    entry = library.require(library.tool_library_path(lock_state.root), config.robot.name, "gripper")
    if outcome.setting_matches is False:
        assert outcome.applied is not None and abs(outcome.applied.mass_kg - entry.mass_kg) < 0.001
    back = outcome.applied or outcome.setting
    # the controller now holds the library's payload: a second verify finds the setting matching
    again = verify_tool(config, VerifyOptions(tool="gripper", assume_yes=True, cell=cell, out=lambda s: None,
                                              detail=lambda s: None, mount=_mount(*TRUTH)))
    assert again.setting_matches is True and again.applied is None and back is not None


def test_a_verify_from_our_own_resting_pose_starts_at_travel_speed(identified):
    """Issue 23: where our last completed motion left the arm (the record in the state folder, matching the live
    angles), the verify's first move runs at travel speed; once someone else moved the arm, the slow approach."""
    import math

    from payload_agent.recording import resting_pose

    config, cell, _ = identified
    root = RobotState.for_config(config).root
    vmax = config.robot.max_joint_speed_rad_s

    def verify():
        lines = []
        o = verify_tool(config, VerifyOptions(tool="gripper", assume_yes=True, cell=cell, out=lines.append,
                                              detail=lambda s: None, mount=_mount(*TRUTH)))
        first = load_manifest(o.run_dir)["plan"][0]
        return o, "\n".join(lines), 100 * math.radians(first["speed_deg_s"]) / vmax

    first, _, _ = verify()
    rec = resting_pose.load(root)
    assert rec is not None and rec.run_dir == str(first.run_dir) and rec.matches(cell.robot.snapshot().q)
    again, text, pct = verify()
    assert "first move runs at travel speed" in text and pct == pytest.approx(config.procedure.travel_speed_percent)
    assert again.robot_time_s <= 5.0
    cell_program_turns_joint_1(cell, 2.0)  # someone else moved the arm: the record no longer matches
    moved, text, pct = verify()
    assert "travel speed" not in text and pct == pytest.approx(config.safety.approach_speed_percent)
    assert resting_pose.load(root).run_dir == str(moved.run_dir)  # and the new record is where it ended


class _DeafController:
    """A driver whose controller accepts the payload write and keeps its old setting (remote mode off, a
    program that sets its own payload)."""

    def __init__(self):
        self.setting = PayloadSetting(1.0, (0.0, 0.0, 0.05))

    def read_payload(self):
        return self.setting

    def write_payload(self, payload):
        pass

    def state(self):
        from payload_agent.types import ControllerState

        return ControllerState(True, detail="LOCAL mode")


def test_a_write_that_did_not_take_fails_loudly_with_the_likely_cause():
    entry = ToolEntry("gripper", 2.0, (40.0, -25.0, 70.0))
    with pytest.raises(CommunicationError) as exc:
        write_and_check(_DeafController(), entry, lambda s: None)
    text = str(exc.value)
    assert "did NOT take" in text and "reads back 1.000 kg" in text and "Likely cause" in text and "LOCAL mode" in text
    assert exc.value.exit_code == 6


def test_tool_changes_through_watch_verify_known_and_identify_new_tools(identified, tmp_path):
    """watch names the tool from the trigger file: a library tool is verified (robot time within 8 s once the arm
    stands at the verify start), a new name is identified and stored, a wrong tool is re-identified."""
    from dataclasses import replace

    from payload_agent.configuration.watch import WatchConfig
    from payload_agent.session.tool_change import change_tool
    from payload_agent.session.watch import watch

    config, cell, _ = identified
    db = library.tool_library_path(RobotState.for_config(config).root)
    trig = tmp_path / "tool-changed"
    wcfg = replace(config, watch=WatchConfig("file", trig, None, 0.01))
    mounted = {"gripper": TRUTH, "vacuum": (1.2, (0.0, 10.0, 60.0)), "3": TRUTH}
    results = []

    def run_tool(name):
        results.append(change_tool(config, name, cell=cell, out=lambda s: None, mount=_mount(*mounted[name])))
        return 0

    for name in ("gripper", "gripper", "vacuum"):
        before = np.asarray(cell.robot.snapshot().q, float)
        trig.write_text(name + "\n")
        assert watch(wcfg, lambda: 1 / 0, run_tool=run_tool, out=lambda s: None, max_runs=1) == 0
    assert [r.action for r in results] == ["verified", "verified", "identified-new"]
    assert results[1].robot_time_s <= 8.0 and results[1].applied, results[1]
    # the identification hands the arm back where the change found it (the last verify's start), so the next
    # known tool starts from its own resting pose near its verify motion
    assert np.max(np.abs(np.asarray(cell.robot.snapshot().q, float) - before)) < np.radians(0.2)
    after_new = change_tool(config, "gripper", cell=cell, out=lambda s: None, mount=_mount(*TRUTH))
    assert after_new.action == "verified" and after_new.robot_time_s <= 8.0, after_new
    vac = library.require(db, config.robot.name, "vacuum")
    assert abs(vac.mass_kg - 1.2) < 0.03 and results[2].run_dirs
    # a tool number names the tool too; a wrong tool under a known name is identified again and stored
    grip = library.require(db, config.robot.name, "gripper")
    library.store(db, config.robot.name, replace(grip, number=3, time_utc=""))
    assert change_tool(config, "3", cell=cell, out=lambda s: None, mount=_mount(*TRUTH)).action == "verified"
    wrong = change_tool(config, "gripper", cell=cell, out=lambda s: None, mount=_mount(2.5, TRUTH[1]))
    assert wrong.action == "identified-mismatch" and len(wrong.run_dirs) == 2
    assert abs(library.require(db, config.robot.name, "gripper").mass_kg - 2.5) < 0.03
    with pytest.raises(Exception, match="tool number 9"):
        change_tool(config, "9", cell=cell, out=lambda s: None)
