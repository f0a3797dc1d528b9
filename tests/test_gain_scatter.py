"""evaluation.systematics.gain_scatter: a gain error per (joint, standing angle) widens σ by what it does; white noise does not.

Synthetic deltas on the EC66 model: poses b and d, joints 2 and 3 swept 55°, every other joint still.
The payload's torque plus white noise, and optionally a relative gain error per (still joint, angle)
(what load-dependent gear ripple does to a joint standing still).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.configuration.config import load_config
from payload_agent.evaluation.systematics import gain_scatter
from payload_agent.solvers import general
from payload_agent.solvers.regressor import payload_regressor
from payload_agent.solvers.wls import cog_with_covariance
from payload_agent.types import SweepKey

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "sim-ec66.yaml"
POSES = {"b": (0.0, -90.0, 0.0, 180.0, -180.0, 0.0), "d": (0.0, -90.0, 0.0, 180.0, -270.0, -90.0)}
THETA = np.array([2.5, 2.5 * 0.04, 2.5 * -0.03, 2.5 * 0.09])  # 2.5 kg at (40, −30, 90) mm
N = 200
SPEED_RAD_S = 0.25


@pytest.fixture(scope="module")
def kin():
    return load_config(CONFIG).robot.kinematics


def deltas(kin, rng, noise_nm: float, gain_std: float) -> dict:
    """Combined sweeps; each (still joint, standing angle) gets one gain error drawn N(0, gain_std)."""
    eps: dict[tuple[int, float], float] = {}
    out = {}
    for pose, q0 in POSES.items():
        for joint in (2, 3):
            q = np.tile(np.radians(q0), (N, 1))
            q[:, joint - 1] += np.linspace(0.0, np.radians(55.0), N)
            qd = np.zeros_like(q)
            qd[:, joint - 1] = SPEED_RAD_S  # the model has the centripetal term of the sweep speed
            Y = payload_regressor(kin, q, qd, np.zeros_like(q))[:, :, :4]
            dtau = Y @ THETA
            for j in range(6):
                if j != joint - 1:
                    e = eps.setdefault((j, round(float(q[0, j]), 6)), float(rng.normal(0.0, gain_std)))
                    dtau[:, j] *= 1.0 + e
            dtau = dtau + rng.normal(0.0, noise_nm, dtau.shape)
            key = SweepKey(pose, joint, "both", 10.0)
            out[key] = DeltaSweep(key, q, dtau, SPEED_RAD_S)
    return out


def cog_error_z(kin, d, extra: np.ndarray) -> np.ndarray:
    est = general.solve(d, kin)
    theta = np.array([est.mass_kg, *(est.mass_kg * np.asarray(est.cog_m))])
    _, cov_c = cog_with_covariance(theta, np.asarray(est.covariance) + extra)
    return (np.asarray(est.cog_m) - THETA[1:] / THETA[0]) / np.sqrt(np.diag(cov_c))


def test_clusters_join_sweeps_where_a_joint_stands_at_the_same_angle(kin):
    d = deltas(kin, np.random.default_rng(1), 0.05, 0.0)
    sweeps = general.select_sweeps(d)
    groups = general.build_groups(sweeps, kin)
    names = dict(zip((g.label for g in groups), gain_scatter.clusters(sweeps, groups)))
    assert names["b-j2-both/j2"] is None  # the moving joint anchors θ
    assert names["b-j2-both/j4"] == names["b-j3-both/j4"] == names["d-j2-both/j4"]  # j4 at 180° throughout
    assert names["b-j2-both/j5"] != names["d-j2-both/j5"]  # j5 at −180° in b, −270° in d


def test_white_noise_shows_no_scatter(kin):
    """Chance scatter does not count: the likelihood-ratio test keeps τ at 0 in nearly every run, and where
    it does not, τ stays far below the 1 % of the next test."""
    taus, ratios = [], []
    for seed in range(20):
        d = deltas(kin, np.random.default_rng(seed), 0.1, 0.0)
        scatter = gain_scatter.measure(d, kin)
        taus.append(scatter.tau)
        noise_var = np.diag(np.asarray(general.solve(d, kin).covariance))
        ratios.append(np.max(np.diag(scatter.covariance) / noise_var))
    assert sum(t > 0 for t in taus) <= 2  # a 1 % test, on a robust C that is a little optimistic
    assert max(taus) < 0.004
    assert float(np.median(ratios)) == 0.0


def test_gain_errors_of_still_joints_widen_sigma_to_cover_them(kin):
    z_without, z_with, taus = [], [], []
    for seed in range(6):
        d = deltas(kin, np.random.default_rng(100 + seed), 0.05, 0.01)
        scatter = gain_scatter.measure(d, kin)
        taus.append(scatter.tau)
        z_without.append(cog_error_z(kin, d, np.zeros((4, 4))))
        z_with.append(cog_error_z(kin, d, scatter.covariance))
        if scatter.tau > 0:
            assert "torque-gain scatter" in gain_scatter.note(scatter)
    rms_without = float(np.sqrt(np.mean(np.square(z_without))))
    rms_with = float(np.sqrt(np.mean(np.square(z_with))))
    assert 0.004 < float(np.median(taus)) < 0.025  # the 1 % drawn, found from the data
    assert rms_without > 3.0  # white-noise σ alone is far too small
    assert 0.4 < rms_with < 1.6  # with the term: about right, not inflated
