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


def _sweep_rows(kin):
    """(pose, joint, q, Y) of every combined sweep: joints 2 and 3 over 55° from each pose, at the sweep speed (the
    model has its centripetal term); Y the payload regressor's mass and first-moment columns."""
    for pose, q0 in POSES.items():
        for joint in (2, 3):
            q = np.tile(np.radians(q0), (N, 1))
            q[:, joint - 1] += np.linspace(0.0, np.radians(55.0), N)
            qd = np.zeros_like(q)
            qd[:, joint - 1] = SPEED_RAD_S
            yield pose, joint, q, payload_regressor(kin, q, qd, np.zeros_like(q))[:, :, :4]


def _with_still_gains(dtau, joint, q, gain_of) -> np.ndarray:
    """dtau with every still joint's torque scaled by 1 + gain_of((joint index, standing angle))."""
    for j in range(6):
        if j != joint - 1:
            dtau[:, j] *= 1.0 + gain_of((j, round(float(q[0, j]), 6)))
    return dtau


def deltas(kin, rng, noise_nm: float, gain_std: float) -> dict:
    """Combined sweeps; each (still joint, standing angle) gets one gain error drawn N(0, gain_std)."""
    eps: dict[tuple[int, float], float] = {}
    out = {}
    for pose, joint, q, Y in _sweep_rows(kin):
        dtau = _with_still_gains(Y @ THETA, joint, q, lambda k: eps.setdefault(k, float(rng.normal(0.0, gain_std))))
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


# -- after a drive-gain calibration at the same standing angles -------------------------------------------------

THETA_REF = np.array([3.0, 0.0, 0.0, 3.0 * 0.08])  # the benchmark's reference: 3 kg at (0, 0, 80) mm


def exact(kin, theta, eps: dict, scale=None) -> dict:
    """Noise-free combined sweeps of payload ``theta`` with the gain error ``eps[(joint, angle)]`` on every still
    joint (the same errors in every run of the arm: ripple frozen at the angle), at calibrated ``scale``."""
    out = {}
    for pose, joint, q, Y in _sweep_rows(kin):
        dtau = _with_still_gains(Y @ theta, joint, q, lambda k: eps.get(k, 0.0))
        if scale is not None:
            dtau = dtau * scale
        key = SweepKey(pose, joint, "both", 10.0)
        out[key] = DeltaSweep(key, q, dtau, SPEED_RAD_S)
    return out


def test_the_scatter_a_calibration_absorbed_moves_both_solvers_as_the_term_says(kin):
    """Ripple frozen at a still joint's angle is in the reference run too. Where the joint also moves in another
    sweep (joints 2 and 3 here) the calibration fits each standing angle its own scale (session 24,
    ``gain_scales.own_scales``): the joint's gain comes from its moving rows, exact whatever the still errors, and
    the term's share w is 0. Before, the calibration took a share of it into every row of the joint, the moving ones
    included, and the three-step solver, which reads only moving rows, moved by −w_k times its response to the
    joint's gain (on the hard arm at 1 % up to +54 g, docs/benchmarks.md "Session 24"). A joint that stands in every
    sweep (the wrist) keeps its share: nothing else tells its gain. The general fit moves by s_k − w_k·g_j, checked on
    noise-free data against what the two solvers actually do."""
    from payload_agent.evaluation.calibration import fit_gains_from_deltas
    from payload_agent.evaluation.systematics import three_step_response

    clean = exact(kin, THETA, {})
    sweeps = general.select_sweeps(clean)
    groups = general.build_groups(sweeps, kin)
    labels = sorted({n for n in gain_scatter.clusters(sweeps, groups) if n is not None})
    eps = {}
    rng = np.random.default_rng(5)
    for g, name in zip(groups, gain_scatter.clusters(sweeps, groups)):
        if name is not None:
            d = next(s for s in sweeps if s.key.name == g.sweep)
            eps[(g.joint, round(float(d.q[0, g.joint]), 6))] = float(rng.normal(0.0, 0.01))
    scale, _, fitted = fit_gains_from_deltas(exact(kin, THETA_REF, eps), kin, np.ones(6), THETA_REF[0],
                                             THETA_REF[1:] / THETA_REF[0])
    assert {1, 2} <= set(fitted)
    assert scale[1] == pytest.approx(1.0, abs=1e-9) and scale[2] == pytest.approx(1.0, abs=1e-9)  # main: off by w·ε
    tool = exact(kin, THETA, eps, scale)
    eps_k = np.zeros(len(labels))  # ε of each cluster, in the order of ``labels``
    for g, name in zip(groups, gain_scatter.clusters(sweeps, groups)):
        if name is not None:
            d = next(s for s in sweeps if s.key.name == g.sweep)
            eps_k[labels.index(name)] = eps[(g.joint, round(float(d.q[0, g.joint]), 6))]

    res = general.fit_model(tool, kin).fit()  # the run's own fit (its weights), as the term uses it
    shares = gain_scatter.absorbed_shares(sweeps, groups, labels, (THETA_REF, fitted))
    assert all(0.0 <= w <= 1.0 + 1e-9 for _, w in shares.values())
    assert all(w == 0.0 for j, w in shares.values() if j in (1, 2))  # they move elsewhere: their own scales
    assert any(w > 0.5 for j, w in shares.values() if j > 2)  # the still wrist: the calibration took it
    # a calibration that recorded where it stood: the same procedure, the same shares; other angles, none
    stood = gain_scatter.standing_angles(exact(kin, THETA_REF, eps), kin)
    assert gain_scatter.absorbed_shares(sweeps, groups, labels, (THETA_REF, fitted, stood)) == shares
    elsewhere = tuple((j, a + 0.1) for j, a in stood)
    assert gain_scatter.absorbed_shares(sweeps, groups, labels, (THETA_REF, fitted, elsewhere)) == {}
    absorbed = gain_scatter.sensitivities(sweeps, groups, res, THETA, labels, absorbed=shares)
    actual = res.theta[:4] - THETA
    assert actual[0] == pytest.approx((absorbed @ eps_k)[0], rel=0.05)

    th0 = three_step_response.theta(clean, kin)
    assert th0 == pytest.approx(THETA, abs=1e-6)
    moved = three_step_response.theta(tool, kin) - th0
    assert abs(moved[0]) < 1e-6  # kg: the three steps read no still row, and the gains of joints 2, 3 are exact


# -- each cluster as well as the data tell it ----------------------------------------------------------------------

def _term(kin, d):
    from payload_agent.solvers.fitted import ALL

    model = general.fit_model(d, kin)
    return gain_scatter.term(d, kin, None, {ALL: (list(model.groups), model.fit())}, ALL, model), model


def test_a_cluster_measured_worse_than_the_scatter_enters_at_the_scatter_size(kin):
    """The still wrist carries a few N·m of payload torque, so its clusters' ε̂ are noisy, while joints 2 and 3 are
    measured to a few hundredths of a per cent: each cluster's error is its posterior given the measured scatter,
    the measurement where it is much better than τ, the scatter's own size where it is much worse."""
    d = deltas(kin, np.random.default_rng(1), 0.1, 0.01)
    out, _ = _term(kin, d)
    assert out is not None and out.scatter.tau > 0
    mean, P = out.posterior()
    t2, C, eps = out.scatter.tau ** 2, np.diag(out.scatter.eps_cov), out.scatter.eps
    sharp, blurred = C < t2 / 16.0, C > 2.0 * t2
    assert sharp.any() and blurred.any()  # the test's data have both kinds
    assert np.all(np.abs(mean[sharp] - eps[sharp]) < np.sqrt(C[sharp]))  # moved by less than its own noise
    assert np.all(np.diag(P)[sharp] < 0.1 * t2)
    assert np.linalg.norm(mean[blurred]) < 0.6 * np.linalg.norm(eps[blurred])  # mostly noise: drawn towards 0
    assert np.all(np.diag(P)[blurred] > 0.6 * t2) and np.all(np.diag(P)[blurred] <= t2 * (1 + 1e-9))
    cols = out.effect_columns()
    assert cols @ cols.T == pytest.approx(np.outer(mean, mean) + P, abs=1e-12)


def test_the_posterior_term_covers_gain_errors_on_every_still_joint(kin):
    """A gain error on every still (joint, angle), the wrist's clusters measured worse than the scatter: the
    term's σ (posterior mean and covariance through S) covers the CoM error they cause, pooled over 8 seeds
    (without it rms(err/σ) is 2.5–4.5 here)."""
    z = []
    for seed in range(8):
        d = deltas(kin, np.random.default_rng(300 + seed), 0.1, 0.01)
        out, _ = _term(kin, d)
        extra = np.zeros((4, 4))
        if out is not None:
            A = out.sens[out.combined] @ out.effect_columns()
            extra = A @ A.T
        z.append(cog_error_z(kin, d, extra))
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all(rms > 0.6) and np.all(rms < 1.5), rms
