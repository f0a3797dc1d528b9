"""The general solver on synthetic Δτ = Y(q)·θ along the planned sweeps of configs/sim-ec66.yaml."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from payload_agent.config import load_config
from payload_agent.delta import DeltaSweep
from payload_agent.planner import make_plan
from payload_agent.solvers import SOLVERS, general

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


def synthetic(sweeps, kin, noise=0.0, rng=None, theta=THETA):
    """Exact Δτ of the model (gravity + centripetal at SPEED_RAD_S), plus optional Gaussian noise."""
    deltas = {}
    for key, q in sweeps:
        dtau = np.zeros_like(q)
        for i, qi in enumerate(q):
            dtau[i, 1:] = general.regressor(kin, qi, range(1, 6), key.joint - 1, SPEED_RAD_S) @ theta
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
    assert SOLVERS["general"] is general.solve


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
        res = general.fit(noisy)
        theta, cov = res["theta"], res["cov"]
        std = np.sqrt(np.diag(cov))
        assert np.all(np.abs(theta - THETA) < 4.5 * std), (trial, theta - THETA, std)
        c, cov_c = general.cog_with_covariance(theta, cov)
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
