"""`calibrate --park`: the calibration ends at its plan's first pose, ready for the tool change, and the run of its
plan after it starts there with no approach and reuses its empty run (issue 22 item 3; docs/benchmarks.md,
session 26). On the simulated EC66 over its real protocol, one simulated arm for all the sessions: where a session
leaves it is where the next one finds it."""

import dataclasses
import json
import math

import numpy as np
import pytest

from conftest import tweak
from payload_agent.configuration.config import parse_config
from payload_agent.errors import SafetyError
from payload_agent.motion import planner
from payload_agent.motion.planner import expected_durations, make_plan, turned_to
from payload_agent.recording import resting_pose
from payload_agent.recording.state import RobotState
from payload_agent.session import baseline as baselines
from payload_agent.session import run_ends
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification
from payload_agent.session.simulation import SimulatedCell
from payload_agent.types import PayloadSetting

REFERENCE = PayloadSetting(5.0, (0.06, 0.0, 0.08))


def _config(sim_ec66_data, tmp_path):
    """The simulated EC66 on a short plan (j2_pair 15 %, 5–25°), starting where the YAML has it (not at the plan's
    first pose); the first move at 15 % instead of 5 % only to keep the test short."""
    data = sim_ec66_data
    for key, value in (("procedure.name", "j2_pair"), ("procedure.speed_percent", 15), ("procedure.sweep_deg", [5, 25]),
                       ("procedure.travel_speed_percent", 25), ("procedure.accel_percent", 100),
                       ("safety.approach_speed_percent", 15), ("robot.name", "park"),
                       ("driver.rpc_port", 0), ("driver.monitor_port", 0)):
        data = tweak(data, key, value)
    data["storage"] = {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")}
    return parse_config(data, str(tmp_path / "park.yaml"))


def _calibrate(config, cell, said):
    return run_identification(config, RunOptions(mode="calibrate", assume_yes=True, report=False, park=True,
                                                 reference=REFERENCE),
                              OperatorUI(out=said.append, progress=False),
                              SimulatedCellUse(cell=cell, on_cell=lambda c: c.change_tool(5.0, (60.0, 0.0, 80.0))))


def test_calibrate_with_the_park_ends_at_the_first_pose_and_the_run_of_its_plan_starts_there(
        sim_ec66_data, tmp_path, monkeypatch):
    """A park move the gate would refuse refuses the session before anything moves (it is checked with the whole
    plan); the real one leaves the arm at the plan's first pose (the live angles) as our resting pose; the run of the
    same plan then makes a first move of no length, records no empty run (the calibration's is subtracted), mounts
    the tool at its own first pose, and identifies the simulation's tool, which the agent was not told."""
    config = _config(sim_ec66_data, tmp_path)
    state = RobotState.for_config(config)
    cell = SimulatedCell(config).start()
    try:
        start = np.asarray(cell.robot.snapshot().q, float)
        assert np.max(np.abs(start - make_plan(config).moves[0].target_rad)) > math.radians(10)  # not there already

        def refused(config, plan):  # the park move turned 250° in joint 1: more than one move may turn
            p = planner.parked(config, plan)
            last = p.moves[-1]
            bad = dataclasses.replace(last, target_rad=(last.target_rad[0] + math.radians(250), *last.target_rad[1:]))
            return dataclasses.replace(p, moves=(*p.moves[:-1], bad))

        with monkeypatch.context() as m:
            m.setattr(run_ends, "parked", refused)
            with pytest.raises(SafetyError, match="(?s)park at .*joint 1 turns 250.*leave --park out"):
                _calibrate(config, cell, [])
        assert np.allclose(cell.robot.snapshot().q, start, atol=1e-3)  # nothing moved (the angles carry noise)
        assert baselines.load_baseline(state) is None and not state.gains_path.exists()

        said: list[str] = []
        cal = _calibrate(config, cell, said)
        text = "\n".join(said)
        assert "park move back to the plan's first pose" in text
        assert text.index("park move") < text.index("Safety gate:") < text.index("[empty] 1/")  # shown before moving
        live = np.asarray(cell.robot.snapshot().q, float)
        first = np.radians(json.loads((cal.run_dir / "manifest.json").read_text())["plan"][0]["target_deg"])
        assert np.max(np.abs(live - first)) < math.radians(0.05)  # the plan's first pose, in the turns the session ran
        rest = resting_pose.standing_at(state.root, live)
        assert rest is not None and rest.run_dir == str(cal.run_dir)
        stored = baselines.load_baseline(state)
        assert stored is not None and stored.plan_fingerprint == make_plan(config).fingerprint()  # the park is no sweep

        cell.change_tool(2.0, (40.0, -25.0, 70.0))  # the operator mounts the tool where the arm waits
        said.clear()
        out = run_identification(config, RunOptions(unattended=True, report=False),
                                 OperatorUI(out=said.append, progress=False), SimulatedCellUse(cell=cell))
        manifest = json.loads((out.run_dir / "manifest.json").read_text())
        assert manifest["phases_planned"] == [["loaded", True]]
        assert manifest["phases"]["empty"]["from_baseline"]["source_run"] == stored.source_run
        assert np.allclose(np.radians(manifest["first_move"]["target_deg"]), live, atol=1e-3)  # no approach
        assert expected_durations(turned_to(config, make_plan(config), live), live)[0] < 0.05  # s (the angles' noise)
        assert "the first move runs at travel speed" in "\n".join(said)
        mount = np.asarray(manifest["phases"]["loaded"]["start_joint_angles_rad"])
        assert np.max(np.abs(mount - first)) < math.radians(0.05)  # the cable's rest: a pose of its own sweeps
        est = out.result.primary
        assert any("empty baseline" in n for n in est.notes), est.notes
        assert abs(1000 * est.mass_kg - 2000.0) < 30 and np.max(np.abs(np.array(est.cog_mm) - [40, -25, 70])) < 5
    finally:
        cell.close()


def test_plan_shows_the_park_move_and_checks_it(sim_ec66_data, tmp_path, capsys):
    """`plan --park` shows the plan as `calibrate --park` runs it, the park move last, and the gate's verdict on it."""
    import yaml

    from payload_agent import cli

    config = _config(sim_ec66_data, tmp_path)
    robot = tmp_path / "park.yaml"
    robot.write_text(yaml.safe_dump(dict(config.raw)))
    start = ",".join(f"{v:g}" for v in config.simulation.start_deg)
    assert cli.main(["plan", "--robot", str(robot), "--from-deg", start, "--park", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    moves = data["plan"]["moves"] if isinstance(data["plan"], dict) else data["plan"]
    assert moves[-1]["label"].startswith("park at") and moves[-1]["target_deg"] == moves[0]["target_deg"]
    assert data["safety"]["ok"]
