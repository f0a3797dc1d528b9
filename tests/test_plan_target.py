"""`plan --target-std G,MM` predicts candidate procedures' σ before moving and names the fastest that meets it."""

import json

import numpy as np

import pytest

from conftest import ROOT
from payload_agent import cli


def test_plan_for_a_target_picks_a_procedure_from_the_declared_noise(capsys):
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--target-std", "20,5", "--json"])
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert rc == 0 and doc["target"]["noise_source"].startswith("effort noise and friction declared")
    chosen = doc["target"]["chosen"]
    assert chosen is not None and chosen["mass_std_g"] <= 20 and chosen["cog_std_mm"] <= 5
    assert "chosen:" in out.err


def test_a_malformed_target_names_the_option(capsys):
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--target-std", "2mm"])
    assert rc == 2 and "--target-std" in capsys.readouterr().err


def test_the_candidates_include_other_procedures_and_every_one_passes_the_safety_gate():
    """The joint-2-only procedures are tried beside the configured one, each plan is checked whole by the
    safety gate, and a procedure the gate refuses (its sweep below the floor) is never chosen."""
    import math

    import numpy as np

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.motion.safety import SafetyGate

    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    noise = design.NoiseModel((0.3,) * 6, 0.008, length_std_m=0.5e-3 / math.sqrt(3), joints=config.robot.joints,
                              friction_level_nm=(4.0, 4.0, 3.0, 1.0, 1.0, 0.5))
    grid = [design.Candidate(10, 25, 0, 20, 1, 100, p) for p in ("", "j2_pair", "j2_triple")]
    grid.append(design.Candidate(10, 25, -60, 20, 1, 100, "j2_pair"))  # below the floor: refused
    choice = design.choose(config, 5.0, 3.0, noise, grid=grid, exhaustive=True)
    by = {(p.candidate.procedure, p.candidate.sweep_from_deg): p for p in choice.table}
    assert not by[("j2_pair", -60)].usable and "floor" in " ".join(by[("j2_pair", -60)].problems)
    for (proc, lo), p in by.items():
        if lo == 0:
            assert p.usable, p.problems
            plan = design.plan_for(config, p.candidate)
            cfg = design.with_candidate(config, p.candidate)
            assert SafetyGate(cfg).check(plan, np.asarray(plan.moves[0].target_rad)).ok
            assert {m.sweep.joint for m in plan.sweeps} == ({2, 3} if proc == "" else {2})
    # joint-2 sweeps only: no 90° joint-2 travel to a joint-3 sweep, so less robot time at the same speed
    assert by[("j2_pair", 0)].robot_time_s < 0.7 * by[("", 0)].robot_time_s
    assert choice.best is not None and choice.best.candidate.procedure in ("j2_pair", "j2_triple")


def test_declared_zero_and_friction_terms_raise_the_predicted_sigma():
    """systematics.planned_covariance's terms enter the prediction: more declared uncertainty, more σ."""
    import dataclasses
    import math

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design

    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    c = design.Candidate(10, 25, 0, 40, 1, 100, "j2_pair")
    theta = design.nominal_theta(2.0, (40, -25, 70))
    plain = design.NoiseModel((0.3,) * 6, 0.008)
    decl = dataclasses.replace(config.robot.joints, zero_offset_std_rad=(math.radians(0.2),) * 6)
    with_terms = dataclasses.replace(plain, joints=decl, friction_level_nm=(4.0, 4.0, 3.0, 1.0, 1.0, 0.5))
    a, b = design.predict(config, c, plain, theta), design.predict(config, c, with_terms, theta)
    assert b.mass_std_g > a.mass_std_g * 1.05 and b.cog_std_mm > a.cog_std_mm


def _plan_json(capsys, monkeypatch, tmp_path, *extra):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--json", *extra])
    out = capsys.readouterr()
    return rc, json.loads(out.out), out.err


def test_the_chosen_row_is_in_the_table_and_its_written_robot_file_plans_the_same_moves(capsys, monkeypatch, tmp_path):
    """The chosen procedure is a marked row of the printed table, and the robot YAML written for it runs through
    the planner into exactly the candidate's moves (procedure file, speeds, acceleration, range)."""
    import numpy as np

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.motion.planner import make_plan

    rc, doc, err = _plan_json(capsys, monkeypatch, tmp_path, "--target-std", "20,5")
    chosen = doc["target"]["chosen"]
    assert rc == 0 and chosen is not None
    marked = [line for line in err.splitlines() if line.rstrip().endswith("<- chosen")]
    assert len(marked) == 1 and marked[0].startswith(chosen["procedure"])
    written = load_config(chosen["robot_file"])
    keys = chosen["procedure_keys"]
    assert written.robot.name == "sim-ec66" and written.procedure.speed_percent == keys["speed_percent"]
    original = load_config(ROOT / "configs" / "sim-ec66.yaml")
    cand = design.Candidate(keys["speed_percent"], keys["travel_speed_percent"], *keys["sweep_deg"], 1,
                            keys["accel_percent"], keys["name"])
    expected, planned = design.plan_for(original, cand), make_plan(written)
    # the target is for mass and CoM: the wrist moves of the inertia part come on top, as the YAML asks
    assert chosen["inertia_part"] == original.procedure.inertia
    mass_cog_moves, extra = planned.moves[:len(expected.moves)], planned.moves[len(expected.moves):]
    assert {m.kind for m in extra} <= {"wrist", "travel"} and (extra == () or original.procedure.inertia)
    for a, b in zip(mass_cog_moves, expected.moves):
        assert a.kind == b.kind and np.allclose(a.target_rad, b.target_rad)
        assert a.speed_rad_s == pytest.approx(b.speed_rad_s) and a.accel_rad_s2 == pytest.approx(b.accel_rad_s2)
    # planning the written file for the same target finds it again: nothing faster meets the target
    assert cli.main(["plan", "--robot", chosen["robot_file"]]) == 0


def test_the_robot_time_counts_the_approach_move_from_where_the_robot_stands(capsys, monkeypatch, tmp_path):
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design

    rc, doc, err = _plan_json(capsys, monkeypatch, tmp_path, "--target-std", "20,5", "--from-deg", "0,-90,90,90,-90,0")
    chosen = doc["target"]["chosen"]
    assert rc == 0 and doc["target"]["approach_counted"]
    keys = chosen["procedure_keys"]
    cand = design.Candidate(keys["speed_percent"], keys["travel_speed_percent"], *keys["sweep_deg"], 1,
                            keys["accel_percent"], keys["name"])
    run_only = design.robot_time_s(design.plan_for(load_config(ROOT / "configs" / "sim-ec66.yaml"), cand))
    assert chosen["robot_time_s"] > run_only + 1.0
    assert "approach move from where the robot stands" in err


def test_from_our_own_resting_pose_the_plan_counts_the_approach_at_travel_speed(capsys, monkeypatch, tmp_path):
    """Where our last completed motion left the arm (the state folder's record matches the angles), `run` makes its
    first move at travel speed; the plan counts the approach so, and says it (issue 22 item 3: after `calibrate`
    the approach was most of the robot time)."""
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.recording import resting_pose
    from payload_agent.recording.state import RobotState

    where = [0, -90, 90, 90, -90, 0]
    args = ("--target-std", "20,5", "--from-deg", ",".join(map(str, where)))
    rc, slow, _ = _plan_json(capsys, monkeypatch, tmp_path, *args)
    assert rc == 0 and not slow["target"]["approach_from_rest"]
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    resting_pose.record(RobotState.for_config(config).root, np.radians(where), tmp_path / "an-earlier-run")
    rc, fast, err = _plan_json(capsys, monkeypatch, tmp_path, *args)
    assert rc == 0 and fast["target"]["approach_from_rest"] and "our own resting pose" in err
    keys = fast["target"]["chosen"]["procedure_keys"]
    cand = design.Candidate(keys["speed_percent"], keys["travel_speed_percent"], *keys["sweep_deg"], 1,
                            keys["accel_percent"], keys["name"])
    q = np.radians(where)
    travel, approach = design.approach_s(config, cand, q, from_rest=True), design.approach_s(config, cand, q)
    assert 0 < travel < 0.5 * approach  # 20 % against 5 %, less the ramps
    run_only = design.robot_time_s(design.plan_for(config, cand))
    assert fast["target"]["chosen"]["robot_time_s"] == pytest.approx(run_only + travel, rel=1e-6)
    assert fast["target"]["chosen"]["robot_time_s"] < slow["target"]["chosen"]["robot_time_s"]


def test_the_expected_payload_is_what_the_prediction_assumes_and_the_output_names_it(capsys, monkeypatch, tmp_path):
    """A heavier expected payload gives a smaller centre-of-mass σ for the same procedure (σ_c ∝ 1/m); the
    output names the payload; a tool library entry can stand for it; a CoM without a mass is refused."""
    from payload_agent.configuration.config import load_config
    from payload_agent.recording.state import RobotState
    from payload_agent.session import target
    from payload_agent.tools import library

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    light = target.expected_payload(config, 1.0, "0,0,50")
    heavy = target.expected_payload(config, 4.0, "0,0,50")
    from payload_agent.evaluation import design

    grid = [design.Candidate(10, 25, 0, 30, 1, 100, "j2_triple")]
    noise, _ = target.noise_for(config)
    a = design.choose(config, 100, 100, noise, nominal_mass_kg=light.mass_kg, nominal_cog_mm=light.cog_mm, grid=grid)
    b = design.choose(config, 100, 100, noise, nominal_mass_kg=heavy.mass_kg, nominal_cog_mm=heavy.cog_mm, grid=grid)
    assert b.table[0].cog_std_mm < 0.5 * a.table[0].cog_std_mm
    db = library.tool_library_path(RobotState.for_config(config).root)
    library.store(db, "sim-ec66", library.ToolEntry("gripper", 3.5, (10.0, 0.0, 90.0)))
    assert target.expected_payload(config, tool="gripper").mass_kg == 3.5
    rc, doc, err = _plan_json(capsys, monkeypatch, tmp_path, "--target-std", "20,5", "--tool", "gripper")
    assert rc == 0 and doc["target"]["payload"]["mass_kg"] == 3.5 and "3.5 kg at 10, 0, 90 mm" in err
    rc, doc, err = _plan_json(capsys, monkeypatch, tmp_path, "--target-std", "20,5", "--payload-cog-mm", "0,0,80")
    assert rc == 2 and "--payload-cog-mm" in err
    rc, doc, err = _plan_json(capsys, monkeypatch, tmp_path, "--payload-kg", "3")
    assert rc == 2 and "--payload-kg" in err and "--target-std" in err


def test_the_prediction_carries_the_stored_calibration_as_the_run_will(monkeypatch, tmp_path):
    """With a stored drive-gain calibration the plan predicts with its gain uncertainty and its reference (whose
    fit absorbs most of the DH-length error), as ``pipeline.run_gains`` gives the run: nominal gains carry
    the whole length term, so the calibrated prediction of a well-determined procedure is smaller."""
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.evaluation.calibration import GainCalibration, calibration_fingerprint, save_calibration
    from payload_agent.recording.state import RobotState
    from payload_agent.session import target

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    nominal, source = target.noise_for(config)
    assert nominal.gain_rel_std is None and "nominal drive gains" in source
    gains = tuple(config.effort.gains_nm_per_unit)
    cal = GainCalibration(gains, (1, 2, 3, 4), (1.0,) * 6, (0.0, 5e-4, 5e-4, 3e-3, 5e-3, 0.0), 3.0, (0.0, 0.0, 0.08),
                          "sim-ec66", config.effort.unit, calibration_fingerprint(config), str(tmp_path), "2026-01-01")
    save_calibration(RobotState.for_config(config).ensure(), cal)
    calibrated, source = target.noise_for(config)
    assert calibrated.gain_rel_std[1] == 5e-4 and calibrated.gain_reference[1] == (1, 2, 3, 4)
    assert "calibration" in source
    cand, theta = design.Candidate(3, 25, 0, 40, 1, 100, "j2_triple"), design.nominal_theta(2.0, (40, -25, 70))
    assert design.predict(config, cand, calibrated, theta).mass_std_g < 0.8 * design.predict(
        config, cand, nominal, theta).mass_std_g


def _stored_run(folder, keep_every: int, time_scale: float = 1.0, period_s: float = 0.008):
    """A stored run's manifest whose sweeps' streams kept every ``keep_every``-th sample (``StreamStats`` as a
    driver fills them: controller clock in robot seconds, receive times ``time_scale`` times faster)."""
    from payload_agent.types import StreamStats

    sweeps = []
    for k, name in enumerate(("b-j2-up", "b-j2-down", "d-j2-up", "d-j2-down")):
        stats = StreamStats(period_s)
        for t in np.arange(0.0, 3.0, period_s)[::keep_every]:
            stats.add(100.0 + t / time_scale, t, 0.05)
        sweeps.append({"name": name, "status": "complete", "samples": stats.count, "stream": stats.to_json()})
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text(json.dumps({"phases": {"empty": {"sweeps": sweeps}}}))


def test_a_thinned_stream_in_the_stored_runs_gives_a_proportionally_larger_noise_term(monkeypatch, tmp_path):
    """The plan assumes the samples per second of sweep the stored runs delivered (their manifests' stream
    statistics, in robot time), and says so; a stream that kept a quarter of its samples doubles the noise
    term's σ (four times its variance); without a stored run the nominal rate, said so."""
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.recording.state import RobotState
    from payload_agent.session import stream_density, target

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    nominal, source = target.noise_for(config)
    assert nominal.sample_period_s == pytest.approx(0.008) and "nominal 125 per s (no stored run" in source
    _stored_run(RobotState.for_config(config).baseline_dir, keep_every=4, time_scale=config.simulation.time_scale)
    thinned, source = target.noise_for(config)
    assert thinned.sample_period_s == pytest.approx(0.032, rel=0.02)
    assert "31 of the nominal 125 samples per s" in source and "drops samples" in source
    cand, theta = design.Candidate(10, 25, 0, 40, 1, 100, "j2_triple"), design.nominal_theta(2.0, (40, -25, 70))
    plan = design.plan_for(config, cand)
    a = design.covariance_terms(config, plan, nominal, theta)[0]["noise"]
    b = design.covariance_terms(config, plan, thinned, theta)[0]["noise"]
    assert b[0, 0] / a[0, 0] == pytest.approx(4.0, rel=0.05)
    # a dense stored stream: the nominal rate again, reported as measured
    dense = stream_density.delivered(config, 0.008, [_dense(tmp_path)])
    assert dense.kept_share == pytest.approx(1.0, abs=0.01) and "dense" in dense.describe()
    # a manifest without the controller clock's rate: the receive rate in real time, nothing in a time-scaled
    # simulation (its samples arrive in bursts)
    entry = {"status": "complete", "stream": {"count": 100, "achieved_rate_hz": 60.0}}
    assert stream_density.sweep_rate_hz(entry, 1.0) == 60.0 and stream_density.sweep_rate_hz(entry, 15.0) is None


def _dense(tmp_path):
    _stored_run(tmp_path / "dense-run", keep_every=1)
    return tmp_path / "dense-run"


def test_a_stream_the_agent_paces_in_a_faster_simulation_has_fewer_samples_per_robot_second(monkeypatch, tmp_path):
    """CANopen SYNC comes from the agent's clock: the simulated arm at time_scale 4 gets a quarter of the SYNC rate
    per simulated second, and the plan counts its samples so; a sweep too short for the quality gate's samples at
    that rate is not a candidate (the plan chose one before, and every run was refused)."""
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.session import target

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-canopen-arm.yaml")
    noise, source = target.noise_for(config)
    assert noise.sample_period_s == pytest.approx(4 / 250) and "nominal 62 per s" in source
    theta = design.nominal_theta(1.5, (25, -15, 50))
    short = design.predict(config, design.Candidate(12, 25, 0, 15, 1, 100), noise, theta, check_safety=False)
    long = design.predict(config, design.Candidate(12, 25, 0, 40, 1, 100), noise, theta, check_safety=False)
    assert not short.usable and "quality gate needs 50" in short.problems[-1]
    assert long.usable and long.samples >= 4 * 100  # four sweeps: the gate's 50 in half of each


def test_plan_for_a_target_without_a_calibration_on_a_robot_reporting_currents(capsys, monkeypatch, tmp_path):
    """A robot whose effort is motor current (UR over Modbus) and no stored calibration or baseline: the plan
    predicts with the nominal gains the run will use (it failed with a TypeError before)."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ur5e-modbus.yaml"), "--target-std", "15,5", "--json"])
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert rc == 0 and "nominal drive gains" in doc["target"]["noise_source"]
    assert doc["target"]["chosen"]["mass_std_g"] <= 15


def test_a_standing_joints_noise_is_measured_and_predicted_apart_from_a_sweeping_ones(monkeypatch, tmp_path):
    """In a joint-2 sweep joint 3 stands but carries the payload's torque; a UR's standing joints are several
    times quieter than moving ones. The baseline's noise is measured per joint sweeping and standing apart, and
    a joint-2-only candidate's noise term follows the standing joint 3's noise (the plan took every joint's
    in-motion noise before: 9.6 g predicted, 5.9 g reported on sim-ur5e-modbus)."""
    import dataclasses

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.evaluation.effort_noise import moving_and_standing_std
    from payload_agent.recording.rundata import SweepData
    from payload_agent.types import SweepKey

    rng = np.random.default_rng(3)
    sigma = {True: np.array([1.8, 2.1, 1.4, 0.7, 0.6, 0.4]), False: np.array([0.6, 0.5, 0.3, 0.2, 0.15, 0.14])}

    def sweep(joint, direction):
        t = np.arange(0.0, 2.0, 0.002)
        q = np.zeros((len(t), 6))
        q[:, joint - 1] = 0.3 * t if direction == "up" else 0.6 - 0.3 * t
        moving = np.arange(6) == joint - 1
        effort = rng.normal(size=(len(t), 6)) * np.where(moving, sigma[True], sigma[False])
        return SweepData(SweepKey("b", joint, direction, 10.0), t, q, effort, direction)

    sweeps = {s.key: s for s in (sweep(j, d) for j in (2, 3) for d in ("up", "down"))}
    moving, standing = moving_and_standing_std(sweeps)
    assert moving[1] == pytest.approx(2.1, rel=0.1) and moving[2] == pytest.approx(1.4, rel=0.1)
    assert standing[1] == pytest.approx(0.5, rel=0.1) and standing[2] == pytest.approx(0.3, rel=0.1)
    assert standing[0] == pytest.approx(0.6, rel=0.1) and moving[0] == standing[0]  # never swept: as standing

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ur5e-modbus.yaml")
    from payload_agent.session import target

    noise, _ = target.noise_for(config)
    assert noise.effort_rest_std_nm == tuple(config.simulation.noise_rest_nm)
    theta = design.nominal_theta(2.5, (30, -20, 60))
    plan = design.plan_for(config, design.Candidate(7, 25, 0, 40, 1, 100, "j2_pair"))
    quiet = design.covariance_terms(config, plan, noise, theta)[0]["noise"]
    loud = design.covariance_terms(config, plan, dataclasses.replace(noise, effort_rest_std_nm=None), theta)[0]["noise"]
    assert quiet[0, 0] < 0.25 * loud[0, 0]


def test_the_controllers_own_constants_count_for_the_joints_a_run_sweeps():
    """Without a calibration a UR run fits the current-to-torque constants from the controller's target signals for
    the joints its sweeps move, and carries their uncertainty for those only (sim-ur5e, j2_pair: joint 2's alone).
    A joint-2-only candidate's gain term then leaves joint 3's out; paper_bd sweeps both, so its term is whole."""
    import dataclasses

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design

    config = load_config(ROOT / "configs" / "sim-ur5e.yaml")
    theta = design.nominal_theta(2.5, (30, -20, 60))
    # a UR's noise: joint 3 standing in a joint-2 sweep is the quiet one, so its rows (and its gain) weigh most
    whole = design.NoiseModel(tuple(config.simulation.noise_nm), 0.002, gain_rel_std=(0.0, 0.016, 0.016, 0.0, 0.0, 0.0),
                              effort_rest_std_nm=tuple(config.simulation.noise_rest_nm))
    swept = dataclasses.replace(whole, gain_swept_only=True)
    for proc, smaller in (("j2_pair", True), ("", False)):
        cand = design.Candidate(10, 25, 0, 40, 1, 100, proc)
        plan = design.plan_for(config, cand)
        a = design.covariance_terms(design.with_candidate(config, cand), plan, whole, theta)[0]["gains"][0, 0]
        b = design.covariance_terms(design.with_candidate(config, cand), plan, swept, theta)[0]["gains"][0, 0]
        assert (b < 0.2 * a) if smaller else b == pytest.approx(a)
