"""The calibration and the tool run subtract ONE empty baseline: its noise is in both and cancels in part, and the
general fit's and the three-step solver's σ count it once, with its correlation (issue 22 items 2 and 5;
evaluation.shared_baseline).

A simulated EC66 at 20 % sweep speed (short sweeps: noise matters) records an empty run, a tool run and a
calibration run with the reference payload. The tool is close to the reference, where the baseline's noise cancels
almost wholly: the uncorrected σ counts it twice (in the fit's noise and in the gains' σ), the corrected one not.
The product's plumbing: ``calibrate`` records which empty run it subtracted, and a run against the same one is
analysed with the correlation, a run against another without."""

import dataclasses
import json

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation import systematics
from payload_agent.evaluation.analyse import AnalysisOptions, Gains, analyse
from payload_agent.evaluation.baseline_identity import empty_run_source, same_baseline
from payload_agent.evaluation.calibration import RUN_CALIBRATION, GainCalibration, fit_from_sweeps
from payload_agent.evaluation.gain_scales import fit_gains_from_deltas
from payload_agent.evaluation.pipeline import run_gains
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import three_step
from recorded_runs import record_runs

from benchmarks.reference import REFERENCE
from benchmarks.remedies import scaled
from conftest import ROOT

TOOL = PayloadTruth.point(3.2, (10.0, -5.0, 70.0))  # near the 3 kg reference at (0, 0, 80) mm; the agent is not told
NOISE_NM = 0.3
DRAWS = 8


def _config():
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    procedure = dataclasses.replace(config.procedure, speed_percent=20.0, inertia=None)
    return dataclasses.replace(config, procedure=procedure)


@pytest.fixture(scope="module")
def clean_runs():
    """Noise-free empty, tool and reference runs of one arm; the tests add the sensor noise, draw by draw."""
    config = _config()
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=3, noise_nm=0.0,
                     friction=FrictionParams((4.0, 4.0, 3.0, 1.0, 1.0, 0.5), (8.0, 8.0, 5.0, 1.0, 1.0, 0.5),
                                             np.full(6, 0.05)))
    empty, loaded, ref = record_runs(robot, plan, TOOL, PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    return config, empty, loaded, ref


def _noisy(sweeps, rng):
    return {k: dataclasses.replace(s, effort_nm=s.effort_nm + rng.normal(0.0, NOISE_NM, s.effort_nm.shape))
            for k, s in sweeps.items()}


def _calibrate(config, ref, empty):
    return fit_from_sweeps(ref, empty, config, REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0,
                           joints=systematics.RIGID)


def _estimate(config, loaded, empty, cal, shared, solver="general"):
    gains = Gains(tuple(cal.gains_nm_per_unit), "test calibration", None, tuple(cal.gain_rel_std(0.0)),
                  cal.reference, cal.zeros, shared_baseline=shared)
    options = AnalysisOptions(config.robot.kinematics, systematics.RIGID, None, solver)
    scale = np.asarray(cal.scale)
    return analyse(scaled(loaded, scale), scaled(empty, scale), options, gains, solvers=()).primary


def _both(config, empty, loaded, ref, rng):
    """(σ with the correlation, σ without, the mass) of one noisy draw of the three runs."""
    e, lo, r = _noisy(empty, rng), _noisy(loaded, rng), _noisy(ref, rng)
    cal = _calibrate(config, r, e)
    shared, independent = _estimate(config, lo, e, cal, True), _estimate(config, lo, e, cal, False)
    assert shared.mass_kg == independent.mass_kg  # the estimate is the same; only its σ changes
    assert any("empty baseline" in n for n in shared.notes)
    assert not any("empty baseline" in n for n in independent.notes)
    return shared.mass_std_kg, independent.mass_std_kg


def test_with_a_tool_like_the_reference_the_baseline_counts_once(clean_runs):
    """Without the correlation, the baseline is about half of the fit's noise and half of the gains' σ (the other
    halves: the tool run's and the reference run's own noise, which stay). With it, most of those halves cancel,
    never more than all of them."""
    config, empty, loaded, ref = clean_runs
    with_corr, without = _both(config, empty, loaded, ref, np.random.default_rng(7))
    assert 0.6 < with_corr / without < 0.9, (with_corr, without)
    assert with_corr ** 2 >= 0.5 * without ** 2 * 0.9  # the tool and reference runs' own halves remain


def test_the_baseline_noise_really_cancels_in_the_calibrated_mass(clean_runs):
    """Over draws of the baseline's noise alone (tool and reference runs fixed), the calibrated mass moves by what
    the corrected σ leaves for the baseline, far less than the independent sum claims (half its variance)."""
    config, empty, loaded, ref = clean_runs
    rng = np.random.default_rng(11)
    with_corr, without = _both(config, empty, loaded, ref, np.random.default_rng(7))
    lo, r = _noisy(loaded, rng), _noisy(ref, rng)
    masses = []
    for _ in range(DRAWS):
        e = _noisy(empty, rng)
        masses.append(_estimate(config, lo, e, _calibrate(config, r, e), True).mass_kg)
    spread = float(np.std(masses, ddof=1))
    claimed_independent = np.sqrt(0.5) * without  # the baseline's share as two independent parts
    left_by_correction = np.sqrt(max(with_corr ** 2 - 0.5 * without ** 2, 0.0))
    assert spread < 0.7 * claimed_independent, (spread, claimed_independent)
    assert spread < 2.0 * left_by_correction, (spread, left_by_correction)


def test_the_three_step_sigma_takes_the_baselines_correlation_the_noise_has(clean_runs):
    """The three steps read three sweeps (joint 2 in pose b, joint 3 in poses b and d), the calibration's scales of
    joints 2 and 3 fit every row of those joints against the same empty run. Over draws of the baseline's noise alone
    (the tool and reference runs' noise fixed), the three steps' estimate at nominal gains, β_0 = β + J·ε_b, and the
    scales' errors δs_j move together; the calibrated estimate is β_0 + Σ_j g_j·δs_j, so its variance is short of the
    independent sum by −2·Cov(β_0, Σ_j g_j·δs_j). The reported σ² (shared minus independent) must say that much.
    Measured on 150 draws the ratio scatters by about ±20 %: on eight other seeds it was 0.77–1.31 (mass) and
    0.74–1.20 (z), here 0.83 / 0.94; without the term the reported difference is zero and the test fails."""
    config, empty, loaded, ref = clean_runs
    kin, nominal = config.robot.kinematics, np.asarray(config.effort.gains_nm_per_unit, float)
    rng = np.random.default_rng(5)
    lo, r = _noisy(loaded, rng), _noisy(ref, rng)
    e = _noisy(empty, rng)
    cal = _calibrate(config, r, e)
    shared = _estimate(config, lo, e, cal, True, "three-step")
    independent = _estimate(config, lo, e, cal, False, "three-step")
    assert shared.mass_kg == independent.mass_kg and shared.cog_m == independent.cog_m  # only σ changes
    assert any("empty baseline" in n for n in shared.notes)
    assert not any("empty baseline" in n for n in independent.notes)
    var = lambda est: np.array([est.mass_std_kg, *est.cog_std_m]) ** 2  # noqa: E731
    reported = var(shared) - var(independent)
    g = three_step.scores(systematics.prepare(lo, e, systematics.RIGID).deltas, kin).gain_response
    betas, moved = [], []
    for _ in range(150):
        e = _noisy(empty, rng)
        betas.append(three_step.scores(systematics.prepare(lo, e, systematics.RIGID).deltas, kin).beta)
        scale, _, fitted = fit_gains_from_deltas(systematics.prepare(r, e, systematics.RIGID).deltas, kin, nominal,
                                                 REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0)
        assert set(fitted) >= {1, 2}
        moved.append(g[1] * scale[1] + g[2] * scale[2])  # Σ_j g_j·δs_j, up to a constant
    betas, moved = np.array(betas), np.array(moved)
    measured = 2.0 * np.mean((betas - betas.mean(axis=0)) * (moved - moved.mean(axis=0)), axis=0) * 150 / 149
    for i, what in ((0, "mass"), (3, "CoM z")):
        assert reported[i] < 0 and measured[i] < 0, (what, reported[i], measured[i])
        assert 0.6 < measured[i] / reported[i] < 1.5, (what, measured[i], reported[i])


def _manifest(folder, empty_phase):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "manifest.json").write_text(json.dumps({"phases": {"empty": empty_phase, "loaded": {}}}))
    return folder


def test_which_empty_run_a_folder_subtracts(tmp_path):
    own = _manifest(tmp_path / "own", {"status": "complete"})
    copied = _manifest(tmp_path / "copied", {"from_baseline": {"dir": "state/x/baseline", "source_run": str(own)}})
    unknown = _manifest(tmp_path / "unknown", {"from_baseline": {"dir": "state/x/baseline"}})
    assert empty_run_source(own) == str(own.resolve())
    assert empty_run_source(copied) == str(own.resolve())
    assert empty_run_source(tmp_path / "elsewhere", baseline_dir=own) == str(own.resolve())
    assert empty_run_source(unknown) is None
    assert empty_run_source(tmp_path / "no-such-folder") is None
    assert same_baseline(empty_run_source(own), empty_run_source(copied))
    assert not same_baseline(None, None)


def test_a_run_against_the_calibrations_baseline_is_analysed_with_the_correlation(tmp_path, clean_runs):
    config, empty, _, ref = clean_runs
    cal_run = _manifest(tmp_path / "calibration-run", {"status": "complete"})  # recorded its own empty run
    cal = dataclasses.replace(_calibrate(config, ref, empty), baseline_source=empty_run_source(cal_run))
    assert GainCalibration.from_json(json.loads(json.dumps(cal.to_json()))) == cal  # gains.json keeps it
    same = _manifest(tmp_path / "same", {"from_baseline": {"dir": "b", "source_run": str(cal_run)}})
    other = _manifest(tmp_path / "other", {"status": "complete"})  # a fresh empty run of its own
    for folder in (same, other):
        (folder / RUN_CALIBRATION).write_text(json.dumps(cal.to_json()))
    assert run_gains(config, same).shared_baseline
    assert not run_gains(config, other).shared_baseline
    old = {k: v for k, v in cal.to_json().items() if k != "baseline_source_run"}  # a gains.json from before
    (same / RUN_CALIBRATION).write_text(json.dumps(old))
    assert not run_gains(config, same).shared_baseline


# -- the plan's prediction of the term (``shared_baseline.planned_cross_covariance``, ``design``) ----------------------

def test_the_plans_term_is_the_runs_on_the_same_rows(clean_runs):
    """``plan --target-std`` predicts the σ a run will report; where the run subtracts the calibration's empty run, that
    σ carries the cross term. The plan's, from its planned rows of the same procedure and white noise of the same
    level, against the run's on a noisy draw of the simulated runs: within the ±20 % a draw's residual σ and the
    run's interpolation of the empty run leave (measured on three draws: 0.83–1.19 per diagonal element). Without the
    plan's term (before session 19) there is no "baseline" part and the prediction lacks the reduction."""
    from payload_agent.evaluation import design, shared_baseline
    from payload_agent.solvers import general

    config, empty, loaded, ref = clean_runs
    rng = np.random.default_rng(5)
    e, lo, r = _noisy(empty, rng), _noisy(loaded, rng), _noisy(ref, rng)
    cal = _calibrate(config, r, e)
    scale, rel = np.asarray(cal.scale), tuple(cal.gain_rel_std(0.0))
    model = general.fit_model(systematics.prepare(scaled(lo, scale), scaled(e, scale), systematics.RIGID).deltas,
                              config.robot.kinematics)
    run = shared_baseline.cross_covariance(model, cal.reference[0], cal.reference[1], rel)[:4, :4]
    noise = design.NoiseModel((NOISE_NM,) * 6, 0.008, gain_rel_std=rel, gain_reference=cal.reference)
    theta = np.array([TOOL.mass_kg, *(TOOL.mass_kg * np.asarray(TOOL.cog_m))])  # the plan's expected payload
    terms, _ = design.covariance_terms(config, make_plan(config), noise, theta, shared=True)
    planned = terms["baseline"]
    for i, what in ((0, "mass"), (3, "m·z")):
        assert planned[i, i] < 0 and run[i, i] < 0, (what, planned[i, i], run[i, i])
        assert 0.8 < planned[i, i] / run[i, i] < 1.25, (what, planned[i, i], run[i, i])
    # a run that records its own empty run shares nothing with the calibration: no term
    assert not np.any(design.covariance_terms(config, make_plan(config), noise, theta)[0]["baseline"])


def test_the_plan_takes_the_term_for_the_candidates_that_reuse_the_calibrations_baseline(clean_runs):
    """A run reuses the stored baseline only when its plan has the baseline's fingerprint; the stored calibration's
    empty run is that baseline when it recorded it. So the candidate whose plan is the calibration's gets the term
    (its predicted mass σ drops), another speed of the same procedure records its own empty run and does not."""
    from payload_agent.evaluation import design
    from payload_agent.evaluation.planned_baseline import SharedBaseline

    config, empty, _, ref = clean_runs
    rng = np.random.default_rng(5)
    cal = _calibrate(config, _noisy(ref, rng), _noisy(empty, rng))
    pc = config.procedure
    same = design.Candidate(pc.speed_percent, pc.travel_speed_percent, pc.sweep_from_deg, pc.sweep_to_deg,
                            accel_percent=pc.accel_percent)
    other = dataclasses.replace(same, speed_percent=15.0)
    shared = SharedBaseline(make_plan(config).fingerprint(), pc.name, pc.speed_percent)
    noise = design.NoiseModel((NOISE_NM,) * 6, 0.008, gain_rel_std=tuple(cal.gain_rel_std(0.0)),
                              gain_reference=cal.reference)
    with_shared = dataclasses.replace(noise, shared_baseline=shared)
    assert shared.reused_by(design.run_config(config, same))
    assert not shared.reused_by(design.run_config(config, other))
    theta = np.array([TOOL.mass_kg, *(TOOL.mass_kg * np.asarray(TOOL.cog_m))])
    predict = lambda c, n: design.predict(config, c, n, theta, check_safety=False)  # noqa: E731
    assert predict(same, with_shared).mass_std_g < 0.9 * predict(same, noise).mass_std_g
    assert predict(other, with_shared).mass_std_g == predict(other, noise).mass_std_g


def test_the_plan_knows_the_stored_baseline_is_the_calibrations(monkeypatch, tmp_path):
    """``plan --target-std`` reads from the robot's state whether the stored calibration subtracted the stored baseline
    (as ``run_gains`` reads it from the run folders later): a calibration whose empty run became the baseline gives
    the plan the baseline's fingerprint, one that recorded another empty run (a later ``baseline``) none."""
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation.calibration import GainCalibration, calibration_fingerprint, save_calibration
    from payload_agent.recording.state import RobotState, write_json_atomic
    from payload_agent.session import baseline as baselines, target
    from payload_agent.types import ControllerInfo

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    state = RobotState.for_config(config).ensure()
    cal_run = tmp_path / "runs" / "calibration-run"
    cal = GainCalibration(tuple(config.effort.gains_nm_per_unit), (1, 2), (1.0,) * 6, (0.0, 5e-4, 5e-4, 0, 0, 0), 3.0,
                          (0.0, 0.0, 0.08), "sim-ec66", config.effort.unit, calibration_fingerprint(config),
                          str(cal_run), "2026-01-01", baseline_source=str(cal_run.resolve()))
    save_calibration(state, cal)
    plan = make_plan(config)
    info = ControllerInfo("sim", "ec66", "1", "0")
    for source, shared in ((cal_run, True), (tmp_path / "runs" / "later-baseline", False)):
        state.baseline_dir.mkdir(parents=True, exist_ok=True)
        write_json_atomic(state.baseline_info_path, baselines.describe_for(config, plan, info, source).to_json())
        noise, _ = target.noise_for(config)
        assert (noise.shared_baseline is not None) == shared
        if shared:
            assert noise.shared_baseline.plan_fingerprint == plan.fingerprint()
            assert noise.shared_baseline.reused_by(config)  # the YAML's own procedure is the baseline's
