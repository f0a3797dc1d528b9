"""The tool run and its drive-gain calibration against ONE empty baseline: their noise correlated, not independent.

Why: a calibration fits each gain scale k_j of joints 2 and 3 from its reference run minus the empty baseline; the
tool run's θ comes from the tool run minus the same baseline (``calibrate`` and ``run`` both reuse the stored
baseline, and the benchmark calibrates against its case's own empty run). The baseline's noise e_b is then in both:

    θ̂ − θ = P·(ε_loaded + ε_b) + Σ_j G_j·δs_j,      δs_j = −a_jᵀ·(ε_reference + ε_b),

with P = (YᵀWY)⁻¹·YᵀW the fit's map, G_j = ∂θ/∂(relative gain of j) (``wls.gain_covariance``), a_j the calibration's
least-squares weights pred_j / Σ pred_j² (pred_j = Y·θ_ref on joint j's rows: the scale fit regresses the measured
reference torque on that prediction, ``gain_scales``), and ε_b the baseline's part of the rows' noise (the entries
of the deltas' noise maps that come from the empty run: the negative ones, ``analysis.delta``). The fit's noise
covariance holds P·Σ_b·Pᵀ and the gain term G_j·s_j²·G_jᵀ holds G_j·a_jᵀ·Σ_b·a_j·G_jᵀ, each as if the other were
independent; the cross term −(P·Σ_b·a_j)·G_jᵀ and its transpose are missing. It is negative along θ_ref: with a tool
like the reference, the baseline's noise cancels in the ratio of the two runs. The benchmark measured it
(docs/benchmarks.md, "Session 14"): at 20 % sweep speed, 4.98 kg, the mass error's spread over noise draws was
3.6 g with the shared baseline and 5.3 g with an independent one.

``cross_covariance`` is that cross term, computed on the tool run's rows, which stand for the calibration's: a
baseline is shared only between runs of the same procedure, so the reference run swept the same angles at the
same sample rate. Σ_b per group is σ_g²·N_b·N_bᵀ with σ_g² the fit's residual variance per independent sample
(the map's mean gain divided out, as ``wls.modelled_noise``). Where the map's a_jᵀ·Σ_b·a_j would exceed the
calibration's own s_j² (another estimator: a sandwich over its residuals), a_j is scaled down to it, so that the
corrected covariance stays what the sum of its parts says (positive semidefinite).

The three-step solver (``three_step_cross_covariance``) is another linear map of the same rows: its β = [m, x, y, z]
moves by Σ_s J_s·ε_s over the three sweeps it reads and by g_j·δs_j with the gains, so c_j = Σ_s J_s·Σ_b·a_j on those
sweeps' rows; ``baseline_shares`` (Σ_b·a_j per row group, scaled down as above) serves both.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from payload_agent.solvers import general, three_step
from payload_agent.solvers.fitted import ALL, FittedModel


def _baseline_noise(noise_map) -> object | None:
    """Σ_b's shape N_b·N_bᵀ (sparse) of one sweep's noise map, and the map's mean gain mean(diag N·Nᵀ)."""
    from scipy import sparse

    N = sparse.csr_matrix(noise_map)
    Nb = N.multiply(N < 0)  # the empty run's samples enter every delta with a minus sign
    return Nb @ Nb.T, float(np.mean(N.multiply(N).sum(axis=1)))


def baseline_shares(model: FittedModel, theta_ref: Sequence[float], fitted_joints: Sequence[int],
                    gain_rel_std: Sequence[float]) -> dict[int, dict[int, np.ndarray]]:
    """Per calibrated joint j, per row group i of the general fit (index into ``groups_of(ALL)``): k_ji =
    f_j·Σ_b,i·a_ji, the covariance of the baseline's noise on those rows with the scale error −δs_j (module
    docstring), f_j ≤ 1 the scale-down to the calibration's own s_j². Any linear estimator β̂ = Σ_i J_i·y_i that the
    gain scales s_j move by g_j·δs_j then has the cross term −Σ_j (c_j·g_jᵀ + g_j·c_jᵀ), c_j = Σ_i J_i·k_ji
    (``cross_term``). Joints without a map on any of their rows, or without a σ, are left out."""
    res = model.fit(ALL)
    groups = model.groups_of(ALL)
    maps: dict[str, tuple] = {}

    def times(i: int, a: np.ndarray) -> np.ndarray | None:
        g = groups[i]
        if g.noise_map is None or g.noise_map.shape[0] != len(g.y):
            return None
        if g.sweep not in maps:
            maps[g.sweep] = _baseline_noise(g.noise_map)
        S_b, mean_gain = maps[g.sweep]
        return (res.noise_sigma_nm[g.label] ** 2 / max(mean_gain, 1e-300)) * np.asarray(S_b @ a).ravel()

    return shares_on_rows(groups, theta_ref, fitted_joints, gain_rel_std, times,
                          general.stands_apart(list(model.sweeps), list(groups)))


def shares_on_rows(groups, theta_ref: Sequence[float], fitted_joints: Sequence[int], gain_rel_std: Sequence[float],
                   baseline_times, apart: Sequence[bool] | None = None) -> dict[int, dict[int, np.ndarray]]:
    """``baseline_shares`` on any rows: ``groups`` the general fit's row groups, ``baseline_times(i, a)`` Σ_b,i·a for
    group i (None: group i has no known baseline part). The run gives Σ_b from the deltas' noise maps, the plan
    (``planned_cross_covariance``) from its white noise model; the calibration's weights a_j and the scale-down are
    the same for both. ``apart``: per group, True where the calibration fits it a scale of its own
    (``general.stands_apart``: a joint standing where it moves in another sweep), so it has no share in s_j; None: every
    group of joint j has one (the plan's rows, which carry no sweeps)."""
    theta_ref = np.asarray(theta_ref, float)[:4]
    out: dict[int, dict[int, np.ndarray]] = {}
    for j in fitted_joints:
        s_j = float(gain_rel_std[j]) if j < len(gain_rel_std) else 0.0
        mine = [i for i, g in enumerate(groups) if g.joint == j and not (apart is not None and apart[i])]
        if s_j <= 0 or not mine:
            continue
        pred_ref = {i: groups[i].Y[:, :4] @ theta_ref for i in mine}
        norm = float(sum(float(p @ p) for p in pred_ref.values()))
        if norm <= 0:
            continue
        k, v = {}, 0.0
        for i in mine:
            a = pred_ref[i] / norm
            ki = baseline_times(i, a)
            if ki is None:
                continue
            k[i] = np.asarray(ki, float)
            v += float(a @ k[i])
        if v <= 0:
            continue
        f = min(1.0, s_j / np.sqrt(v))  # the map's baseline share of the gain's variance at most the whole of it
        out[j] = {i: f * ki for i, ki in k.items()}
    return out


def cross_term(c: dict[int, np.ndarray], g: dict[int, np.ndarray]) -> np.ndarray:
    """−Σ_j (c_j·g_jᵀ + g_j·c_jᵀ) over the joints both have: c_j = Cov(β̂'s baseline noise, −δs_j), g_j = ∂β̂/∂s_j."""
    n = len(next(iter(g.values()))) if g else 0
    X = np.zeros((n, n))
    for j in sorted(set(c) & set(g)):
        X -= np.outer(c[j], g[j])
    return X + X.T


def cross_covariance(model: FittedModel, theta_ref: Sequence[float], fitted_joints: Sequence[int],
                     gain_rel_std: Sequence[float]) -> np.ndarray:
    """The (p, p) covariance to add to the general fit's θ (noise + gain terms) when the calibration of
    ``fitted_joints`` (reference θ_ref, relative σ ``gain_rel_std`` per joint) used this run's empty baseline:
    Σ_j −(c_j·G_jᵀ + G_j·c_jᵀ), c_j = P·Σ_b·a_j (module docstring). Zero where no row has a noise map."""
    res = model.fit(ALL)
    return fit_cross_term(model.groups_of(ALL), res.weights, res.normal_inverse, res.theta,
                          baseline_shares(model, theta_ref, fitted_joints, gain_rel_std))


def fit_cross_term(groups, weights: np.ndarray, normal_inverse: np.ndarray, theta: np.ndarray,
                   shares: dict[int, dict[int, np.ndarray]]) -> np.ndarray:
    """The general fit's cross term from its rows (``groups``, row ``weights``, (YᵀWY)⁻¹, θ) and the baseline's shares
    on them (``shares_on_rows``): c_j = P·k_j, G_j = ∂θ/∂(relative gain of j) as ``wls.gain_covariance``."""
    inv, w = normal_inverse, np.asarray(weights, float)
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    c, G = {}, {}
    for j, k in shares.items():
        G[j] = sum((inv @ (g.Y.T @ (w[starts[i]:starts[i + 1]] * (g.Y @ theta)))  # ∂θ/∂ε_j, as wls.gain_covariance
                    for i, g in enumerate(groups) if g.joint == j), np.zeros(len(theta)))
        c[j] = inv @ sum((groups[i].Y.T @ (w[starts[i]:starts[i + 1]] * ki) for i, ki in k.items()),
                         np.zeros(len(theta)))
    return cross_term(c, G) if G else np.zeros((len(theta), len(theta)))


def planned_cross_covariance(groups, weights: np.ndarray, theta: np.ndarray, theta_ref: Sequence[float],
                             fitted_joints: Sequence[int], gain_rel_std: Sequence[float]) -> np.ndarray:
    """The cross term a run of planned rows will report (``evaluation.design``, issue 22): the general fit's on
    ``groups`` with row ``weights`` 1/σ² of white delta noise, θ the nominal payload. The loaded and the empty run
    carry equal noise (the plan's model: each delta row's variance is twice one run's, halved where two legs are
    averaged), so the baseline's part of a row is half its variance, Σ_b,i = I/(2·w_i), and independent between
    samples (the run's interpolation of the empty run spreads each of its samples over neighbouring rows with
    weights summing to one, which leaves a smooth a_j's aᵀΣ_b·a as it is)."""
    w = np.asarray(weights, float)
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    Y = np.vstack([g.Y for g in groups])
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)
    shares = shares_on_rows(groups, theta_ref, fitted_joints, gain_rel_std,
                            lambda i, a: a / (2.0 * w[starts[i]:starts[i + 1]]))
    return fit_cross_term(groups, w, inv, np.asarray(theta, float), shares)


def three_step_cross_covariance(model: FittedModel, theta_ref: Sequence[float], fitted_joints: Sequence[int],
                                gain_rel_std: Sequence[float]) -> np.ndarray:
    """The (4, 4) covariance to add to the three-step solver's θ = [m, m·c] (noise + gain terms) on ``model``'s
    deltas, where the calibration used this run's empty baseline: the same cross term through the three steps.

    The three steps are, to first order, β̂ − β = Σ_s J_s·ε_s over the three sweeps they read (joint 2's rows of
    the joint-2 sweep in pose b, joint 3's of the joint-3 sweeps in poses b and d; ``three_step.Scores``), and a
    gain scale error δs_j moves β̂ by g_j·δs_j (g_j = Σ J_s·pred_s over joint j's sweeps, the three-step's own gain
    term). The baseline's noise on J_s's samples is the noise on the general fit's rows of the same sweep and joint
    (same delta, same samples): c_j = Σ_s J_s·k_js (``baseline_shares``; rows of other joints or sweeps are
    independent of them and add nothing). The cross term −(c_j·g_jᵀ + g_j·c_jᵀ) is added in β and carried to θ
    with the solver's own ∂θ/∂β (``three_step.theta_jacobian``)."""
    sc = three_step.scores(model.deltas, model.kin)
    groups = model.groups_of(ALL)
    c = {}
    for j, k in baseline_shares(model, theta_ref, fitted_joints, gain_rel_std).items():
        c[j] = np.zeros(4)
        for i, ki in k.items():
            J = sc.rows.get((groups[i].sweep, groups[i].joint))
            if J is not None and J.shape[1] == len(ki):
                c[j] += J @ ki
    Jt = three_step.theta_jacobian(sc.beta)
    return Jt @ cross_term(c, sc.gain_response) @ Jt.T if c else np.zeros((4, 4))


def note(mass_std_before_kg: float, mass_std_after_kg: float) -> str:
    """What the result's notes say about the correction."""
    return (f"the drive-gain calibration used this run's empty baseline: the baseline's noise, in both, is "
            f"counted once with its correlation (mass σ {1000 * mass_std_before_kg:.2f} → "
            f"{1000 * mass_std_after_kg:.2f} g)")


__all__ = ["baseline_shares", "cross_covariance", "cross_term", "fit_cross_term", "note", "planned_cross_covariance",
           "shares_on_rows", "three_step_cross_covariance"]
