"""The torque-gain term a run carries where it stands at the calibration's angles, predicted before it.

Why. After a drive-gain calibration that stored each standing angle's own gain error ε̂ ± σ_ε
(``reference_shares.ReferenceShares.scales``), a run whose still joint stands at one of those angles has its rows
divided by 1 + ε̂ (``calibration_clusters``), and its torque-gain term gives that cluster the prior variance σ_ε²
(what ε̂ missed) in place of the scatter's size τ², even where the run finds no scatter (``gain_scatter.
corrected_prior``). Under that prior the term's expectation is S·diag(σ_ε²)·Sᵀ (E[ε̃ε̃ᵀ] + P = V, ``gain_scatter``),
S the fit's response to each corrected cluster's gain error, less what the calibration absorbed: a property of where
the procedure stands and of the calibration, known before the run. ``plan --target-std`` adds it so that a procedure
standing at the calibration's angles is predicted as the run will report it. The scatter of the clusters not
corrected (τ, measured from the run's own data, 0 on most arms) stays unpredicted.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation import calibration_clusters
from payload_agent.evaluation.systematics import gain_scatter
from payload_agent.solvers import wls


def corrected_covariance(sweeps: Sequence[DeltaSweep], groups: Sequence[wls.Group], w: np.ndarray,
                         normal_inverse: np.ndarray, theta: np.ndarray, gain_reference: tuple | None) -> np.ndarray:
    """(4, 4) S·diag(σ_ε²)·Sᵀ over the clusters of the planned ``sweeps`` whose rows the calibration's per-angle gain
    errors will correct (``calibration_clusters.matches``: within its tolerance of a stored angle), for the fit of
    ``groups`` with row weights ``w`` and (YᵀWY)⁻¹ ``normal_inverse`` at ``theta``; zeros where none will be."""
    groups = list(groups)
    sweeps = predicted(list(sweeps), groups, theta)
    found = calibration_clusters.matches(sweeps, gain_reference)
    if not found:
        return np.zeros((4, 4))
    names = gain_scatter.clusters(sweeps, groups)
    var = {name: found[(g.sweep, g.joint)][1] ** 2 for g, name in zip(groups, names) if (g.sweep, g.joint) in found}
    labels = sorted(var)
    shares = calibration_clusters.uncorrected(gain_scatter.absorbed_shares(sweeps, groups, labels, gain_reference),
                                              sweeps, groups, names, gain_reference)
    S = gain_scatter.sensitivities(sweeps, groups, _planned_fit(theta, w, normal_inverse), theta, labels,
                                   absorbed=shares)
    return (S * np.array([var[label] for label in labels])) @ S.T


def predicted(sweeps: list[DeltaSweep], groups: Sequence[wls.Group], theta: np.ndarray) -> list[DeltaSweep]:
    """The planned ``sweeps`` with the planned payload's torque Y·θ as their loaded − empty torque: the sign a run's
    still rows will have there, which decides whether a never-turning joint's stored error applies
    (``calibration_clusters.matches``)."""
    dtau = {d.key.name: np.array(d.dtau, float) for d in sweeps}
    for g in groups:
        dtau[g.sweep][:, g.joint] = g.Y[:, :4] @ np.asarray(theta, float)[:4]
    return [replace(d, dtau=dtau[d.key.name]) for d in sweeps]


def _planned_fit(theta: np.ndarray, w: np.ndarray, normal_inverse: np.ndarray) -> wls.FitResult:
    """The fit of the planned rows as ``gain_scatter.sensitivities`` reads a run's: its weights and (YᵀWY)⁻¹."""
    return wls.FitResult(theta=np.asarray(theta, float), cov=normal_inverse, cov_iid=normal_inverse, sigma_nm={},
                         weights=w, normal_inverse=normal_inverse, residual_rms_nm={}, condition_number=float("nan"),
                         s2=1.0, n=len(w), tau={}, inflation=1.0)


__all__ = ["corrected_covariance"]
