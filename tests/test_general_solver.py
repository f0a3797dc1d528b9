"""The general solver on synthetic Δτ = Y(q)·θ along the planned sweeps of configs/sim-ec66.yaml."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from payload_agent.configuration.config import load_config
from payload_agent.analysis.delta import DeltaSweep
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import SOLVERS, general, regressor, wls

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "sim-ec66.yaml"
TRUTH_M, TRUTH_C = 2.0, np.array([0.040, -0.025, 0.070])
THETA = np.concatenate(([TRUTH_M], TRUTH_M * TRUTH_C))


def planned_sweeps(bidirectional: bool = False, n: int = 200):
    """(key, q (n, 6)) for every sweep move of the plan, sampled uniformly along the move."""
    config = load_config(CONFIG)
    if bidirectional:
        config = dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, bidirectional=True))
    plan = make_plan(config)
    out, prev = [], None
    for move in plan.moves:
        target = np.asarray(move.target_rad)
        if move.sweep is not None:
            s = np.linspace(0.02, 0.98, n)[:, None]  # the constant-speed part, away from the ends
            out.append((move.sweep, prev + s * (target - prev)))
        prev = target
    return config, out


SPEED_RAD_S = 0.025  # the sweeps' constant speed (only the small centripetal term depends on it)


_REGRESSORS: dict[tuple, np.ndarray] = {}


def sweep_regressors(kin, key, q) -> np.ndarray:
    """The general solver's regressor rows (n, 5, 4) of one sweep, computed once per arm, joint and angles:
    several tests evaluate the same sweeps with another θ or another noise draw."""
    cache_key = (kin.rows, key.joint, np.asarray(q, float).tobytes())
    if cache_key not in _REGRESSORS:
        _REGRESSORS[cache_key] = np.stack([regressor.regressor(kin, qi, range(1, 6), key.joint - 1, SPEED_RAD_S)
                                           for qi in q])
    return _REGRESSORS[cache_key]


def synthetic(sweeps, kin, noise=0.0, rng=None, theta=THETA):
    """Exact Δτ of the model (gravity + centripetal at SPEED_RAD_S), plus optional Gaussian noise."""
    deltas = {}
    for key, q in sweeps:
        dtau = np.zeros_like(q)
        dtau[:, 1:] = sweep_regressors(kin, key, q) @ theta
        if noise:
            dtau = dtau + rng.normal(0.0, noise, dtau.shape)
        deltas[key] = DeltaSweep(key, q, dtau, SPEED_RAD_S)
    return deltas


@pytest.fixture(scope="module")
def setup():
    config, sweeps = planned_sweeps()
    kin = config.robot.kinematics
    # regressor rows are the expensive part: compute them once, reuse for every noisy trial
    clean = synthetic(sweeps, kin)
    return kin, clean


def test_registered():
    assert SOLVERS["general"].solve is general.solve


def test_noise_free_recovers_theta(setup):
    kin, clean = setup
    est = general.solve(clean, kin)
    theta = np.concatenate(([est.mass_kg], est.mass_kg * np.asarray(est.cog_m)))
    assert np.max(np.abs(theta - THETA)) / np.max(np.abs(THETA)) < 1e-9
    assert est.condition_number is not None and est.condition_number < 1e4
    assert all(v < 1e-8 for v in est.residual_rms_nm.values())
    # joint 1 carries nothing; joints 2..6 appear
    assert not any(k.endswith("/j1") for k in est.residual_rms_nm)
    assert any(k.endswith("/j2") for k in est.residual_rms_nm)


def _groups_cache(kin, clean):
    sweeps = general.select_sweeps(clean)
    return general.build_groups(sweeps, kin)


def test_noisy_error_within_reported_std_and_ci_coverage(setup):
    kin, clean = setup
    groups = _groups_cache(kin, clean)
    rng = np.random.default_rng(12345)
    # a different noise level per joint, as on a real arm (big joints noisier)
    sigma_j = {2: 0.3, 3: 0.3, 4: 0.08, 5: 0.08, 6: 0.05}
    covered_m = covered_c = 0
    trials = 100
    for trial in range(trials):
        noisy = [dataclasses.replace(g, y=g.y + rng.normal(0.0, sigma_j[int(g.label.rsplit("j", 1)[1])], len(g.y)))
                 for g in groups]
        res = wls.fit(noisy)
        theta, cov = res.theta, res.cov
        std = np.sqrt(np.diag(cov))
        assert np.all(np.abs(theta - THETA) < 4.5 * std), (trial, theta - THETA, std)
        c, cov_c = wls.cog_with_covariance(theta, cov)
        covered_m += abs(theta[0] - TRUTH_M) <= 1.96 * std[0]
        covered_c += np.all(np.abs(c - TRUTH_C) <= 1.96 * np.sqrt(np.diag(cov_c)))
        if trial == 0:
            assert std[0] < 0.01  # a few grams with 0.3 N·m noise: sanity of the scale
    assert covered_m >= 85, covered_m
    # three components jointly inside their 95 % intervals: ≈ 0.95³ ≈ 86 % expected
    assert covered_c >= 75, covered_c


def test_end_to_end_noisy_estimate_fields(setup):
    config, sweeps = planned_sweeps()
    kin = config.robot.kinematics
    deltas = synthetic(sweeps, kin, noise=0.3, rng=np.random.default_rng(7))
    est = general.solve(deltas, kin)
    assert abs(est.mass_kg - TRUTH_M) < 4 * est.mass_std_kg
    assert np.all(np.abs(np.asarray(est.cog_m) - TRUTH_C) < 4 * np.asarray(est.cog_std_m))
    assert len(est.covariance) == 4
    d = est.to_json()
    assert "mass_ci95_kg" in d and "cog_ci95_mm" in d and "condition_number" in d


def test_single_pose_restriction(setup):
    kin, clean = setup
    for pose in ("b", "d"):
        est = general.solve(clean, kin, poses=[pose])
        assert abs(est.mass_kg - TRUTH_M) < 1e-9


def _with_length(kin, row: int, which: str, delta_m: float):
    from payload_agent.model.kinematics import Kinematics

    rows = list(kin.rows)
    rows[row] = dataclasses.replace(rows[row], **{f"{which}_m": getattr(rows[row], f"{which}_m") + delta_m})
    return Kinematics(tuple(rows))


def test_kinematic_uncertainty_term(setup):
    kin, clean = setup
    deltas = synthetic(planned_sweeps()[1], kin, noise=0.3, rng=np.random.default_rng(3))
    base = general.solve(deltas, kin)
    # zero uncertainty: the covariance is exactly the noise (and gain) covariance
    assert np.array_equal(general.solve(deltas, kin, length_std_m=0.0).covariance, base.covariance)
    small = general.solve(deltas, kin, length_std_m=0.0002)
    large = general.solve(deltas, kin, length_std_m=0.001)
    cov0, cov_s, cov_l = (np.asarray(e.covariance) for e in (base, small, large))
    # the added term is σ²·SᵀS: positive semi-definite and quadratic in the declared σ
    assert np.all(np.linalg.eigvalsh(cov_s - cov0) > -1e-18)
    assert np.allclose(cov_l - cov0, 25.0 * (cov_s - cov0), rtol=1e-9, atol=1e-20)
    assert np.all(np.asarray(large.cog_std_m) > np.asarray(small.cog_std_m))
    assert np.all(np.asarray(small.cog_std_m) > np.asarray(base.cog_std_m))
    assert large.mass_std_kg > base.mass_std_kg
    assert (large.mass_kg, large.cog_m) == (base.mass_kg, base.cog_m)  # the estimate itself is unchanged


def test_kinematic_sensitivity_predicts_length_error(setup):
    """Data from an arm whose a2 is 0.5 mm longer, solved with the nominal lengths: the first-order
    sensitivity the covariance is built from predicts the resulting error of θ̂."""
    kin, clean = setup
    config, sweeps = planned_sweeps()
    params = general.length_parameters(kin)
    assert (1, "a") in params and (0, "a") not in params  # a1 = 0 on the EC66: structural, exact
    k = params.index((1, "a"))
    true_kin = _with_length(kin, 1, "a", 0.0005)
    deltas = synthetic(sweeps, true_kin)
    sel = general.select_sweeps(deltas)
    groups = general.build_groups(sel, kin)
    res = wls.fit(groups)
    S = general.kinematic_sensitivities(sel, kin, groups, res.weights, res.normal_inverse, res.theta)
    err = res.theta - THETA
    assert np.max(np.abs(err)) > 1e-4  # the length error matters ...
    assert np.allclose(err, S[k] * 0.0005, rtol=0.02, atol=2e-6)  # ... and is predicted to first order


def test_kinematic_sensitivity_after_gain_calibration(setup):
    """A gain calibration on the same (wrong-length) arm absorbs part of the length error; with the
    calibration's reference the sensitivity predicts what is left."""
    from payload_agent.evaluation.calibration import fit_gains_from_deltas

    kin, _ = setup
    _, sweeps = planned_sweeps()
    true_kin = _with_length(kin, 1, "a", 0.0005)
    ref_m, ref_c = 3.0, np.array([0.0, 0.0, 0.080])
    theta_ref = np.concatenate(([ref_m], ref_m * ref_c))
    scale, _, fitted = fit_gains_from_deltas(synthetic(sweeps, true_kin, theta=theta_ref), kin, np.ones(6),
                                             ref_m, ref_c)
    tool = {k: DeltaSweep(k, d.q, d.dtau * scale, d.speed_rad_s) for k, d in synthetic(sweeps, true_kin).items()}
    sel = general.select_sweeps(tool)
    groups = general.build_groups(sel, kin)
    res = wls.fit(groups)
    k = general.length_parameters(kin).index((1, "a"))
    S_cal = general.kinematic_sensitivities(sel, kin, groups, res.weights, res.normal_inverse, res.theta, (theta_ref, fitted))
    S_raw = general.kinematic_sensitivities(sel, kin, groups, res.weights, res.normal_inverse, res.theta)
    err = res.theta - THETA
    assert np.allclose(err, S_cal[k] * 0.0005, rtol=0.05, atol=5e-6)
    assert abs(S_cal[k][0]) < abs(S_raw[k][0])  # the calibration took out part of the mass error
