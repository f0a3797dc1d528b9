"""The standing angles of a joint that never turns in the calibration: each a scale of its own around the joint's gain.

Why. A strain-wave gear's load-dependent mesh ripple is, on a joint that stands while another sweeps, a gain error of
that standing angle (docs/benchmarks.md, sessions 24 and 26). A joint that also turns in another sweep gets its gain
from its moving rows and each standing angle its own scale (``gain_scales.own_scales``). The wrist never turns in the
j2 procedures: its gain was one fit over all its standing angles, which absorbed their mean error and left the spread
between them to nothing. Here every such (joint, angle, torque sign) cluster gets a scale of its own as well, *relative*
to the joint's gain k̄ = Σ_c w_c·k_c, w_c the cluster's share of the joint's information (Σ pred² on its rows): the
pooled fit's gain when nothing else is fitted, so a tool run's row at an angle the calibration never stood at gets the
clusters' mean, as before. The cluster's ε̂_c = k_c/k̄ − 1 is stored and taken off the tool run's rows standing there
(``calibration_clusters``).

Why the sign. The simulated gear's ripple grows with |τ| (``fakes.effects.TorqueRipple``), so on the loaded − empty
difference of a joint whose own empty torque is small it is a gain error ε·sign(Δτ): the wrist standing at 180° with
the payload's torque of one sign in one pose and of the other in the next carries +ε in one and −ε in the other, which
the pooled gain averages away and leaves in the centre of mass (realistic+ripple 1 %, case 12: CoM z +0.69 mm, +0.24 mm
with the ripple's load part a factor on the signed torque, +0.19 mm without any ripple; docs/benchmarks.md, session 26).
A real gear's kinematic error gives a factor on the signed torque (virtual work; docs/sources.md, "Strain-wave gear
ripple"), the same for both signs. Splitting by the sign of the reference payload's torque lets the data decide: under
the signed form both halves measure the same ε (the split costs precision only), under the |τ| form they measure
opposite ones. A tool run's rows are corrected only where its own torque there has the sign the calibration's had; rows
of the other sign keep the pooled gain and fall to the torque-gain scatter term, as before.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation.systematics import gain_scatter
from payload_agent.solvers.wls import Group

SIGNS = {1: "+", -1: "-"}


def signed_clusters(sweeps: list[DeltaSweep], groups: list[Group], theta_ref: Sequence[float],
                    min_signal_to_noise: float) -> list[tuple[str, int, float, int] | None]:
    """Per group: (name, joint, angle rad, sign) of its (joint, standing angle, sign of the reference's torque) cluster
    where its joint moves in none of ``sweeps`` and stands in two or more such clusters that carry the reference's
    torque; None elsewhere (a joint that turns somewhere: ``gain_scales.own_scales``; one cluster: it is the gain).

    A cluster carries the reference's torque where its largest |Δτ_pred| is ``min_signal_to_noise`` times the
    residual σ of its joint's pooled fit (Δτ_meas = k·Δτ_pred over all its rows): the gain fit's own test of a joint
    (``gain_scales.MIN_SIGNAL_TO_NOISE``), here per cluster. One below it has no scale to measure and keeps the
    pooled gain, as its rows did before the relative scales: an off-axis reference (5 kg at 60, 0, 80 mm) puts
    almost no torque on the wrist standing at ±90° (a 1e-11 share of its information), and that cluster's own
    column made joint 6's scale 0.986 ± 162 (docs/benchmarks.md, session 26)."""
    theta = np.asarray(theta_ref, float)
    by_name = {d.key.name: d for d in sweeps}
    moves = {g.joint for g in groups if by_name[g.sweep].moving == g.joint}
    preds = [g.Y[:, :len(theta)] @ theta for g in groups]
    sigma: dict[int, float] = {}
    for j in {g.joint for g in groups} - moves:
        p = np.concatenate([pr for g, pr in zip(groups, preds) if g.joint == j])
        y = np.concatenate([g.y for g in groups if g.joint == j])
        k = float(p @ y) / max(float(p @ p), 1e-300)
        sigma[j] = float(np.sqrt(np.sum((y - k * p) ** 2) / max(len(y) - 1, 1)))
    out: list[tuple[str, int, float, int] | None] = []
    for g, name, pred in zip(groups, gain_scatter.clusters(sweeps, groups), preds):
        if name is None or g.joint in moves or np.max(np.abs(pred)) <= gain_scatter.MIN_CLUSTER_PEAK_NM:
            out.append(None)
            continue
        sign = 1 if float(np.mean(pred)) > 0 else -1
        out.append((name + SIGNS[sign], g.joint, float(np.median(by_name[g.sweep].q[:, g.joint])), sign))
    peak: dict[str, float] = {}
    for c, pred in zip(out, preds):
        if c is not None:
            peak[c[0]] = max(peak.get(c[0], 0.0), float(np.max(np.abs(pred))))
    out = [c if c is not None and peak[c[0]] >= min_signal_to_noise * sigma[c[1]] else None for c in out]
    per_joint: dict[int, set[str]] = {}
    for c in out:
        if c is not None:
            per_joint.setdefault(c[1], set()).add(c[0])
    return [c if c is not None and len(per_joint[c[1]]) > 1 else None for c in out]


def base_first(names: Sequence[str], info: Sequence[float]) -> list[str]:
    """``names`` with the best-determined cluster (largest ``info``, its Σ pred²) first: the one whose gain a fit
    takes as its joint's column, the others' differences to it in columns of their own (``relative_map``). A cluster
    with little information as the joint's column leaves the gain's direction of the covariance all but undetermined
    (joint 6 at −90° above: a share of 4e-11), which the fits' pseudo-inverses do not survive."""
    best = int(np.argmax(info))
    return [names[best], *names[:best], *names[best + 1:]]


def relative_map(n_coef: int, k_col: int, cluster_cols: Sequence[int | None], info: Sequence[float]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(a, R): the joint's gain k̄ = a·coef and each cluster's k_c − k̄ = R_c·coef, from a fit whose column ``k_col``
    is the gain of the first cluster (no column of its own: ``cluster_cols[c]`` None; the best-determined one,
    ``base_first``) and whose column ``cluster_cols[c]`` is cluster c's k_c − k_first; ``info``: each cluster's
    Σ pred² (its weight in k̄)."""
    w = np.asarray(info, float) / max(float(np.sum(info)), 1e-300)
    a = np.zeros(n_coef)
    a[k_col] = 1.0
    for wc, col in zip(w, cluster_cols):
        if col is not None:
            a[col] += wc
    R = np.zeros((len(cluster_cols), n_coef))
    for c, col in enumerate(cluster_cols):
        R[c, k_col] = 1.0
        if col is not None:
            R[c, col] += 1.0
        R[c] -= a
    return a, R


def relative_errors(coef: np.ndarray, cov: np.ndarray, floor: np.ndarray | None, a: np.ndarray, R: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(ε̂, σ_ε) per cluster: (k_c − k̄)/k̄ and its σ from the coefficients' covariance, never below what ``floor``
    (the white-noise covariance, or None) gives (k̄'s own error is second order)."""
    k = float(a @ coef)
    var = np.einsum("ij,jk,ik->i", R, cov, R)
    if floor is not None:
        var = np.maximum(var, np.einsum("ij,jk,ik->i", R, floor, R))
    if not k > 0:  # no reference torque on the joint: no gain, no relative errors (never stored: ``kept``)
        return np.full(len(R), np.nan), np.full(len(R), np.inf)
    return (R @ coef) / k, np.sqrt(np.maximum(var, 0.0)) / k


def kept(own: dict[str, tuple[float, float]], relative: Sequence[str]) -> dict[str, tuple[float, float]]:
    """``own`` without the relative clusters (``signed_clusters``) whose σ_ε is not below the scatter τ̂ between the
    standing angles of the joints that turn (their ε̂ against the moving rows' gain, ``gain_scales.own_scales``: the
    same gears' ripple, measured to ±0.1 %; maximum likelihood, ``gain_scatter.scatter_variance``). Correcting a
    cluster swaps the scatter's prior τ² for σ_ε² (``gain_scatter.corrected_prior``), worth it only where σ_ε < τ̂;
    where the calibration finds no scatter (τ̂ = 0) none is taken off, as before. Not the relative clusters' own ε̂:
    where the reference's torque is a few mN·m (joint 5 at 90° with a zero offset, hard scenario) their ratio holds
    whatever else that joint's rows carry, 1800 ± 100 times the torque, and the likelihood read that as scatter."""
    turning = [n for n in own if n not in relative]
    if len(turning) == len(own):
        return dict(own)
    eps = np.array([own[n][0] for n in turning])
    tau = float(np.sqrt(gain_scatter.scatter_variance(eps, np.diag([own[n][1] ** 2 for n in turning]))))
    return {n: v for n, v in own.items() if n not in relative or v[1] < tau}


__all__ = ["SIGNS", "signed_clusters", "base_first", "relative_map", "relative_errors", "kept"]
