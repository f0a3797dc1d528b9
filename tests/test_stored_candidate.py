"""`plan --target-std` offers the run that reuses the stored baseline: the stored calibration's (or baseline's) plan
exactly, beside the grid, and the file it writes for it runs that plan (issue 22 items 3 and 4; session.stored_candidate).

A run reuses the stored empty run only when its plan has the baseline's fingerprint; the grid's speeds, ranges,
travel speed and accelerations never made the plan a calibration records at the YAML's travel and acceleration, so
no candidate shared the calibration's empty run (docs/benchmarks.md, "Session 19: the plan's shared-baseline term")."""

import dataclasses
import json

import numpy as np
import yaml

from conftest import ROOT, fast_start, tweak
from payload_agent import cli
from payload_agent.configuration.config import load_config, parse_config
from payload_agent.evaluation import design
from payload_agent.evaluation.candidates import CONFIGURED, candidates_for
from payload_agent.motion.planner import make_plan
from payload_agent.recording.state import RobotState, write_json_atomic
from payload_agent.session import baseline as baselines
from payload_agent.session.stored_candidate import grid_for
from payload_agent.types import ControllerInfo, PayloadSetting


def _store(config, recorded):
    """A stored baseline of ``recorded``'s plan (its description only: the plan reads no sweeps from it here)."""
    state = RobotState.for_config(config).ensure()
    state.baseline_dir.mkdir(parents=True, exist_ok=True)
    info = baselines.describe_for(recorded, make_plan(recorded), ControllerInfo("sim", "ec66", "1", "0"),
                                  state.root / "runs" / "some-run")
    write_json_atomic(state.baseline_info_path, info.to_json())
    return info


def _reusing(config, grid, info):
    """The candidates whose run reuses the stored baseline (``SharedBaseline.reused_by``: the fingerprint, after a
    cheap screen on the procedure's name and sweep speed)."""
    from payload_agent.evaluation.planned_baseline import SharedBaseline

    stored = SharedBaseline(info.plan_fingerprint, info.procedure, info.speed_percent)
    return [c for c in grid if stored.reused_by(design.run_config(config, c))]


def test_the_grid_holds_the_stored_baselines_plan_exactly_when_one_is_stored(monkeypatch, tmp_path):
    """Without a stored baseline the grid is the grid; with one recorded as `calibrate --procedure j2_triple
    --speed-percent 7` records it (the YAML's travel speed, acceleration and range; the inertia part left out, which
    sim-ec66's YAML has), exactly one candidate makes its plan, and none of the grid's did; a baseline of the YAML's
    own procedure gives the YAML's inertia part; one stored before its keys were recorded, or whose plan today's YAML
    no longer makes, gives none."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    assert config.procedure.inertia is not None
    assert grid_for(config) == candidates_for(config)
    calibrated = dataclasses.replace(config, procedure=dataclasses.replace(
        config.procedure, name="j2_triple", speed_percent=7.0, inertia=None))
    info = _store(config, calibrated)
    grid = grid_for(config)
    assert _reusing(config, candidates_for(config), info) == []
    reusing = _reusing(config, grid, info)
    assert len(reusing) == 1 and len(grid) == len(candidates_for(config)) + 1
    c = reusing[0]
    assert c.stored_baseline and c.inertia is None and c.procedure == "j2_triple"
    assert (c.speed_percent, c.travel_percent, c.accel_percent, c.sweep_from_deg, c.sweep_to_deg) == (
        7.0, config.procedure.travel_speed_percent, config.procedure.accel_percent, config.procedure.sweep_from_deg,
        config.procedure.sweep_to_deg)
    # the YAML's own procedure: the candidate keeps the YAML's inertia part, and the written keys do not touch it
    info = _store(config, config)
    (c,) = _reusing(config, grid_for(config), info)
    assert c.stored_baseline and c.inertia == CONFIGURED and c.procedure == ""
    from payload_agent.session.target_file import procedure_keys

    assert "inertia" not in procedure_keys(config, c)
    # today's YAML turns the arm elsewhere: the stored plan cannot be made, and no candidate claims it
    moved = dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, base_deg=30.0))
    assert grid_for(moved) == candidates_for(moved)
    # a baseline stored before its procedure keys were recorded
    state = RobotState.for_config(config)
    data = json.loads(state.baseline_info_path.read_text())
    del data["procedure_keys"]
    write_json_atomic(state.baseline_info_path, data)
    assert grid_for(config) == candidates_for(config)


def test_after_calibrate_the_plan_chooses_the_calibrations_plan_and_its_run_reuses_the_calibrations_empty_run(
        sim_ec66_data, monkeypatch, tmp_path, capsys):
    """The whole flow on the simulated EC66 over its real protocol: `calibrate` on a procedure off the grid (j2_pair
    15 %, 5–25°: its first pose is where the robot stands, so with the approach counted it is the fastest), then
    `plan --target-std`, then `run` of the file it wrote. The plan chooses the calibration's plan, and that run records
    no empty run: it subtracts the calibration's, and its σ says so."""
    from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    data = sim_ec66_data
    for key, value in (("procedure.name", "j2_pair"), ("procedure.speed_percent", 15), ("procedure.sweep_deg", [5, 25]),
                       ("procedure.travel_speed_percent", 25), ("procedure.accel_percent", 100),
                       ("driver.rpc_port", 0), ("driver.monitor_port", 0)):  # ephemeral ports, as test_workflow's
        data = tweak(data, key, value)
    data = fast_start(data)
    data["storage"] = {"runs_dir": str(tmp_path / "runs")}
    robot = tmp_path / "ec66.yaml"
    robot.write_text(yaml.safe_dump(data))
    config = parse_config(data, source=str(robot), base_dir=tmp_path)
    assert all(c.sweep_from_deg == 0.0 for c in candidates_for(config))  # the calibration's range is not the grid's
    quiet = OperatorUI(progress=False, out=lambda *_: None)
    run_identification(config, RunOptions(mode="calibrate", assume_yes=True, report=False,
                                          reference=PayloadSetting(5.0, (0.06, 0.0, 0.08))), quiet,
                       SimulatedCellUse(on_cell=lambda cell: cell.change_tool(5.0, (60.0, 0.0, 80.0))))
    stored = baselines.load_baseline(RobotState.for_config(config))
    assert stored is not None and stored.plan_fingerprint == make_plan(config).fingerprint()

    assert cli.main(["plan", "--robot", str(robot), "--target-std", "20,5", "--json"]) == 0
    chosen = json.loads(capsys.readouterr().out)["target"]["chosen"]
    assert chosen["reuses_stored_baseline"] and chosen["procedure_keys"]["sweep_deg"] == [5.0, 25.0]
    written = load_config(chosen["robot_file"])
    assert make_plan(written).fingerprint() == stored.plan_fingerprint

    out = run_identification(written, RunOptions(unattended=True, report=False), quiet)
    manifest = json.loads((out.run_dir / "manifest.json").read_text())
    assert manifest["phases"]["empty"]["from_baseline"]["source_run"] == stored.source_run
    # no empty run before it: the loaded run starts where the robot stood, not where the plan ends (the rest of a
    # cable's spring in the run's wrist term, and so in the plan's draws for this candidate)
    start = np.asarray(manifest["phases"]["loaded"]["start_joint_angles_rad"])
    assert np.allclose(start, np.radians(data["simulation"]["start_deg"]), atol=1e-3)
    assert not np.allclose(start, make_plan(written).moves[-1].target_rad, atol=1e-2)
    assert any("empty baseline" in n for n in out.result.primary.notes), out.result.primary.notes
    truth = np.array([2.0, 40.0, -25.0, 70.0])  # the YAML's simulated tool, which the agent was not told
    est = out.result.primary
    assert abs(1000 * est.mass_kg - 1000 * truth[0]) < 30 and np.max(np.abs(np.array(est.cog_mm) - truth[1:])) < 5


def test_calibrate_takes_the_range_travel_and_acceleration_of_a_candidate(monkeypatch, tmp_path, capsys):
    """`calibrate --procedure j2_triple --speed-percent 7 --sweep-deg 0,15 --travel-speed-percent 25 --accel-percent
    100` records the grid candidate's sweeps and moves (the inertia part left out, as `--procedure` does), so the plan
    offers that candidate's plan as the stored baseline's; bad values are refused by name before anything starts."""
    from payload_agent.calibrate_args import with_procedure, with_speed, with_sweep_and_motion
    from payload_agent.session import runner

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    assert with_sweep_and_motion(config) is config
    cal = with_sweep_and_motion(with_procedure(with_speed(config, 7.0), "j2_triple"), "0,15", 25.0, 100.0)
    grid_twin = design.Candidate(7.0, 25.0, 0.0, 15.0, 1, 100.0, "j2_triple")
    assert grid_twin in candidates_for(config)
    assert make_plan(cal).fingerprint() == make_plan(design.run_config(
        config, dataclasses.replace(grid_twin, inertia=None))).fingerprint()
    _store(config, cal)
    stored = [c for c in grid_for(config) if c.stored_baseline]
    assert stored == [dataclasses.replace(grid_twin, inertia=None, stored_baseline=True)]
    started = []
    monkeypatch.setattr(runner, "run_identification", lambda *a, **k: started.append(a))
    for option, bad in (("--sweep-deg", "0,5"), ("--sweep-deg", "15"), ("--travel-speed-percent", "40"),
                        ("--accel-percent", "0")):
        rc = cli.main(["calibrate", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--yes", "--known-mass", "5",
                       "--known-cog", "60,0,80", option, bad])
        err = capsys.readouterr().err
        assert rc == 2 and option in err and "Traceback" not in err, err
    assert started == []


def test_the_plans_cable_rest_for_a_run_that_reuses_the_baseline_is_where_the_run_starts_in_the_plans_turns():
    """A run that reuses the stored baseline starts its loaded run where the robot stands, and turns its moves by whole
    turns to start near there: the spring's lever q − rest the plan draws is the one that run will have, also when
    the robot stands a whole wrist turn away from the plan's own angles (the plan's end as the rest, as for a run with
    its own empty run, or the standing angles unturned, were 0.3-2π off here)."""
    import math

    from payload_agent.evaluation.planned_baseline import reusing_run_mount
    from payload_agent.motion.planner import turned_to

    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    c = design.Candidate(7.0, 25.0, 0.0, 15.0, 1, 100.0, "j2_triple")
    plan = design.plan_for(config, c)
    targets = np.array([m.target_rad for m in plan.moves])
    limits, margin = config.robot.joint_limits_rad, config.safety.joint_limit_margin_rad
    turns = [(j, k) for j in (3, 4, 5) for k in (-1, 1) if np.all(targets[:, j] + 2 * math.pi * k >= limits[j][0] + margin)
             and np.all(targets[:, j] + 2 * math.pi * k <= limits[j][1] - margin)]
    assert turns  # a wrist joint the run can turn a whole turn within its limits
    start = targets[0] + np.array([0.0, 0.1, -0.1, 0.3, 0.2, -0.2])
    start[turns[0][0]] += 2 * math.pi * turns[0][1]  # the robot stands a whole turn away there
    mount = reusing_run_mount(design.with_candidate(config, c), plan, start)
    ran = turned_to(design.with_candidate(config, c), plan, start)
    for planned, run in zip(plan.sweeps, ran.sweeps):
        assert np.allclose(np.asarray(planned.target_rad) - mount, np.asarray(run.target_rad) - start)
    assert not np.allclose(mount, start) and not np.allclose(mount, plan.moves[-1].target_rad)
