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
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from payload_agent.solvers.fitted import ALL, FittedModel


def _baseline_noise(noise_map) -> object | None:
    """Σ_b's shape N_b·N_bᵀ (sparse) of one sweep's noise map, and the map's mean gain mean(diag N·Nᵀ)."""
    from scipy import sparse

    N = sparse.csr_matrix(noise_map)
    Nb = N.multiply(N < 0)  # the empty run's samples enter every delta with a minus sign
    return Nb @ Nb.T, float(np.mean(N.multiply(N).sum(axis=1)))


def cross_covariance(model: FittedModel, theta_ref: Sequence[float], fitted_joints: Sequence[int],
                     gain_rel_std: Sequence[float]) -> np.ndarray:
    """The (p, p) covariance to add to the general fit's θ (noise + gain terms) when the calibration of
    ``fitted_joints`` (reference θ_ref, relative σ ``gain_rel_std`` per joint) used this run's empty baseline:
    Σ_j −(c_j·G_jᵀ + G_j·c_jᵀ), c_j = P·Σ_b·a_j (module docstring). Zero where no row has a noise map."""
    res = model.fit(ALL)
    groups = model.groups_of(ALL)
    inv, w, theta = res.normal_inverse, res.weights, res.theta
    theta_ref = np.asarray(theta_ref, float)[:4]
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    maps: dict[str, tuple] = {}
    X = np.zeros((len(theta), len(theta)))
    for j in fitted_joints:
        s_j = float(gain_rel_std[j]) if j < len(gain_rel_std) else 0.0
        mine = [i for i, g in enumerate(groups) if g.joint == j]
        if s_j <= 0 or not mine:
            continue
        pred_ref = {i: groups[i].Y[:, :4] @ theta_ref for i in mine}
        norm = float(sum(float(p @ p) for p in pred_ref.values()))
        if norm <= 0:
            continue
        h, v, G = np.zeros(len(theta)), 0.0, np.zeros(len(theta))
        for i in mine:
            g, sl = groups[i], slice(starts[i], starts[i + 1])
            G += inv @ (g.Y.T @ (w[sl] * (g.Y @ theta)))  # ∂θ/∂ε_j, as wls.gain_covariance
            if g.noise_map is None or g.noise_map.shape[0] != len(g.y):
                continue
            if g.sweep not in maps:
                maps[g.sweep] = _baseline_noise(g.noise_map)
            S_b, mean_gain = maps[g.sweep]
            a = pred_ref[i] / norm
            Sa = (res.sigma_nm[g.label] ** 2 / max(mean_gain, 1e-300)) * (S_b @ a)
            h += g.Y.T @ (w[sl] * Sa)
            v += float(a @ Sa)
        if v <= 0:
            continue
        f = min(1.0, s_j / np.sqrt(v))  # the map's baseline share of the gain's variance at most the whole of it
        c = f * (inv @ h)
        X -= np.outer(c, G)
    return X + X.T


def note(mass_std_before_kg: float, mass_std_after_kg: float) -> str:
    """What the result's notes say about the correction."""
    return (f"the drive-gain calibration used this run's empty baseline: the baseline's noise, in both, is "
            f"counted once with its correlation (mass σ {1000 * mass_std_before_kg:.2f} → "
            f"{1000 * mass_std_after_kg:.2f} g)")


__all__ = ["cross_covariance", "note"]
