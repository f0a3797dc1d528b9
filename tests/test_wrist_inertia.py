"""The inertia part's analysis: the fit on a simulated recording, consistency, the refusal, the run-folder round trip."""

import numpy as np
import pytest
import yaml

from benchmarks.inertia import one_joint_procedure
from conftest import ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.configuration.procedure import load_procedure
from payload_agent.configuration.wrist_procedure import load_wrist_procedure, parse_wrist_procedure
from payload_agent.evaluation.wrist_inertia import identify_inertia, identify_or_none
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.base import sim_robot_kwargs
from payload_agent.fakes.offline import record_wrist_moves
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.model.arm_geometry import ArmGeometry
from payload_agent.motion.planner import Plan, expected_durations, wrist_moves
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.rundata import load_wrist_moves
from payload_agent.solvers.inertia_fit import fit_inertia
from payload_agent.solvers.inertia_consistency import consistency_problem, project_consistent, to_vector
from payload_agent.evaluation.analyse import Gains
from payload_agent.evaluation.pipeline import add_inertia
from payload_agent.solvers.results import Estimate, RunResult, format_table
from payload_agent.types import Sample

GRIPPER = np.array([[0.012, 0.001, -0.002], [0.001, 0.020, 0.003], [-0.002, 0.003, 0.015]])  # kg·m², about the CoM


@pytest.fixture(scope="module")
def ec66():
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "safety.max_wrist_speed_percent", 100)
    cfg = parse_config(data, source="sim-ec66.yaml")
    geo = ArmGeometry(cfg.robot.kinematics, 0.0)
    margin = cfg.safety.joint_limit_margin_rad
    limits = [(a + margin, b - margin) for a, b in cfg.robot.joint_limits_rad[3:]]
    start = np.radians([0, -90, 90, 180, -270, -90])  # where paper_bd's last sweep leaves the EC66
    moves = wrist_moves(cfg, load_wrist_procedure("wrist_inertia"), geo, limits, tuple(start))
    return cfg, Plan(load_procedure("paper_bd"), tuple(moves)), start


def record(cfg, plan, start, payload, seed):
    kw = sim_robot_kwargs(cfg)
    kw.update(q0_rad=start, seed=seed, payload=payload)
    return record_wrist_moves(SimRobot(SPECS[cfg.simulation.arm](), tick_s=0.008, **kw), plan)[0]


def static(mass, cog_m):
    theta = np.array([mass, *(mass * np.asarray(cog_m))])
    return theta, np.diag([0.01 * mass, 1e-4 * mass, 1e-4 * mass, 1e-4 * mass]) ** 2  # what the sweeps give


def write_run(run_dir, plan, phases, gains):
    """The recorded wrist moves of both phases in a run folder, as the session writes them (effort / gain)."""
    rec = RunRecorder(run_dir, {"format": "payload-agent-run/1", "phases": {}})
    moves = {m.wrist: m for m in plan.wrist_moves}
    for phase, records in phases.items():
        rec.begin_phase(phase)
        for name, r in records.items():
            rec.begin_sweep(moves[name])
            for t, q, tau in zip(r.t, r.q, r.effort_nm):
                rec.sink(Sample(float(t), float(t), tuple(q), tuple(tau / gains)))
            rec.end_sweep("complete")
        rec.end_phase("complete")


def test_a_run_folder_with_wrist_moves_gives_a_gripper_tensor_beside_mass_and_cog(tmp_path, ec66):
    cfg, plan, start = ec66
    cog = (0.04, -0.025, 0.07)
    empty = record(cfg, plan, start, None, 1)
    loaded = record(cfg, plan, start, PayloadTruth.from_tensor(2.0, cog, GRIPPER), 2)
    gains = np.asarray(cfg.effort.gains_nm_per_unit)
    write_run(tmp_path / "run", plan, {"empty": empty, "loaded": loaded}, gains)
    theta, cov = static(2.0, cog)
    primary = Estimate("general", 2.0, cog, mass_std_kg=0.02, covariance=cov)
    result = add_inertia(cfg, RunResult("sim-ec66", str(tmp_path / "run"), primary), tmp_path / "run", None,
                         Gains(tuple(gains), "nominal"))
    out = result.to_json()
    assert np.asarray(out["inertia_com_kgm2"]).shape == (3, 3) and len(out["forms"]["ur"]["inertia_kgm2"]) == 6
    table = format_table(result, {"mass_kg": 2.0, "cog_mm": [40, -25, 70], "inertia_com_kgm2": GRIPPER.tolist()})
    assert "inertia about the CoM" in table and "truth: Ixx 0.01200" in table
    res = identify_inertia(loaded, empty, cfg.robot.kinematics, theta, cov)
    assert np.allclose(res.estimate_kgm2, out["inertia_com_kgm2"], atol=1e-4)  # the folder kept what was recorded
    largest = float(np.max(np.linalg.eigvalsh(GRIPPER)))
    err = res.estimate_kgm2 - GRIPPER
    print(f"condition number {res.condition_number:.3g}; error / largest moment {np.max(np.abs(err)) / largest:.3f}; "
          f"σ {np.round(np.diag(res.std_kgm2), 4)}")
    assert res.refused is None and res.inconsistent_data is None
    assert len(res.moves) == len(plan.wrist_moves) == 16  # procedures/wrist_inertia.yaml: 8 moves there and back
    assert np.max(np.abs(err)) < 0.25 * largest
    assert np.all(np.abs(err) < 3.0 * res.std_kgm2)  # the σ covers the error
    assert consistency_problem(res.estimate_kgm2) is None



def test_wrist_joints_turned_together_carry_more_information_than_one_at_a_time_in_the_same_robot_time(ec66):
    """The shipped procedure turns joints 4, 5 and 6 together; the one before it turned one joint per move (6, 5, 4,
    6 back). Same arm, tool, seeds and noise: the fit's own σ (without the declared model term) must be clearly
    smaller for about the same robot time, or turning them together was not worth it (docs/analysis.md)."""
    cfg, plan, start = ec66
    old = one_joint_procedure()
    geo = ArmGeometry(cfg.robot.kinematics, 0.0)
    margin = cfg.safety.joint_limit_margin_rad
    limits = [(a + margin, b - margin) for a, b in cfg.robot.joint_limits_rad[3:]]
    one = Plan(plan.procedure, tuple(wrist_moves(cfg, parse_wrist_procedure(old), geo, limits, tuple(start))))
    cog = (0.04, -0.025, 0.07)
    truth = PayloadTruth.from_tensor(2.0, cog, GRIPPER)
    stat, seconds = {}, {}
    for name, p in (("together", plan), ("one at a time", one)):
        fit = fit_inertia(record(cfg, p, start, truth, 4), record(cfg, p, start, None, 3), cfg.robot.kinematics,
                          *static(2.0, cog))
        stat[name] = np.sqrt(np.diag(fit.cov)[4:] - fit.systematic_std ** 2)  # flange-origin elements, the data's σ
        seconds[name] = float(np.nansum(expected_durations(p, start)))
    print({k: np.round(v, 5) for k, v in stat.items()}, seconds)
    assert seconds["together"] <= seconds["one at a time"] + 0.5
    assert np.max(stat["together"]) < 0.7 * np.max(stat["one at a time"])
    assert np.mean(stat["together"]) < 0.7 * np.mean(stat["one at a time"])


def test_a_light_compact_tool_gets_mass_and_cog_but_its_inertia_is_refused(ec66):
    cfg, plan, start = ec66
    cog = (0.0, 0.0, 0.02)
    tiny = np.diag([2e-4, 2e-4, 1.5e-4])  # a 0.4 kg flange plate
    empty = record(cfg, plan, start, None, 3)
    loaded = record(cfg, plan, start, PayloadTruth.from_tensor(0.4, cog, tiny), 4)
    res = identify_inertia(loaded, empty, cfg.robot.kinematics, *static(0.4, cog))
    assert res.refused is not None and "largest principal moment" in res.refused
    assert res.inertia_com_kgm2 is None and res.to_json()["inertia_com_kgm2"] is None
    assert res.to_json()["inertia"]["refused"] == res.refused


def test_an_impossible_tensor_is_projected_onto_the_consistent_set():
    bad = np.diag([0.01, 0.01, 0.03])  # 0.03 > 0.01 + 0.01: no rigid body has it
    cov = np.diag([1e-6, 1e-8, 1e-8, 1e-6, 1e-8, 4e-6])  # Izz the least certain
    fixed, why = project_consistent(bad, cov)
    assert why is not None and "triangle" in why
    assert consistency_problem(fixed) is None or "triangle" not in consistency_problem(fixed)
    moments = np.linalg.eigvalsh(fixed)
    assert moments[2] <= moments[0] + moments[1] + 1e-9 and moments[0] >= -1e-12
    # the covariance metric moves the least certain element most
    change = np.abs(to_vector(fixed) - to_vector(bad))
    assert change[5] > change[0] and change[5] > change[3]
    negative = np.diag([0.02, 0.015, -0.004])
    fixed, why = project_consistent(negative, np.eye(6) * 1e-6)
    assert "positive definite" in why and np.min(np.linalg.eigvalsh(fixed)) >= -1e-12
    ok = np.diag([0.01, 0.012, 0.015])
    same, why = project_consistent(ok, np.eye(6) * 1e-6)
    assert why is None and np.array_equal(same, ok)


def test_wrist_moves_round_trip_through_the_run_folder(tmp_path, ec66):
    cfg, plan, _ = ec66
    rec = RunRecorder(tmp_path / "run", {"format": "payload-agent-run/1", "phases": {}})
    rec.begin_phase("loaded")
    move = plan.wrist_moves[0]
    rec.begin_sweep(move)
    for k in range(30):
        rec.sink(Sample(0.008 * k, 100.0 + 0.008 * k, tuple(np.full(6, 0.01 * k)), tuple(np.full(6, 2.0))))
    rec.end_sweep("complete")
    rec.end_phase("complete")
    manifest = rec.manifest
    assert manifest["phases"]["loaded"]["sweeps"] == []
    assert [e["name"] for e in manifest["phases"]["loaded"]["wrist_moves"]] == [move.wrist]
    back = load_wrist_moves(tmp_path / "run", "loaded", np.full(6, 0.5))
    assert list(back) == [move.wrist]
    got = back[move.wrist]
    assert got.q.shape == (30, 6) and got.effort_nm[0, 0] == pytest.approx(1.0) and got.t[1] == pytest.approx(0.008)
    # a run without wrist moves: no inertia part, nothing refused
    assert load_wrist_moves(tmp_path / "run", "empty", np.ones(6)) == {}
    assert identify_or_none({}, {}, cfg.robot.kinematics, *static(1.0, (0, 0, 0.05))) is None
