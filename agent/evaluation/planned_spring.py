"""The cable spring a run of the planned sweeps fits, predicted before it (for ``planned_terms``): its κ covariance C
and map AM onto θ (``spring_covariance``), and what a run with a declared cable adds to σ
(``declared_spring_covariance``), as ``systematics.cable_spring`` computes them from the run's own rows."""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.solvers import wls


def spring_covariance(sweeps: Sequence[DeltaSweep], groups: Sequence[wls.Group], w: np.ndarray, inflation: float,
                      theta: np.ndarray, gain_rel_std: Sequence[float] | None, mount_rad: Sequence[float]
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    """(AM, C) of the cable spring a run of these rows fits (``cable_spring.fit_spring``, no gain scatter found): C
    the κ block of the fit beside θ and one nuisance offset per moving arm joint (``cable_spring.moving_arm_joint``),
    its noise the rows' white noise × ``inflation`` plus the drive gains' part, and AM the map of κ onto θ through
    the plain fit's wrist-offset sensitivities; None when no wrist joint has a lever."""
    fitted = _spring_fit(sweeps, groups, w, inflation, theta, gain_rel_std, mount_rad)
    if fitted is None:
        return None
    AM, C_noise, kappa_gains, _ = fitted
    return AM, C_noise + sum((np.outer(k, k) for k in kappa_gains), np.zeros_like(C_noise))


def declared_spring_covariance(sweeps: Sequence[DeltaSweep], groups: Sequence[wls.Group], w: np.ndarray,
                               inflation: float, theta: np.ndarray, gain_rel_std: Sequence[float] | None,
                               mount_rad: Sequence[float]) -> np.ndarray | None:
    """What a run with a declared cable adds to the plain fit's covariance (``cable_spring.term``): κ̂'s noise
    through AM and the drive gains' response of the corrected θ̂ in place of the plain fit's
    (``cable_spring.corrected_columns``); None when no wrist joint has a lever."""
    from payload_agent.evaluation.systematics import cable_spring

    fitted = _spring_fit(sweeps, groups, w, inflation, theta, gain_rel_std, mount_rad)
    if fitted is None:
        return None
    cols, sign = cable_spring.corrected_columns(*fitted)
    return (cols * sign) @ cols.T


def _spring_fit(sweeps, groups, w, inflation, theta, gain_rel_std, mount_rad):
    """(AM, κ̂'s noise covariance, [κ̂'s response to each drive gain's σ], [the plain θ̂'s, same gains]) of the
    spring fit a run of these rows makes (``spring_covariance``); None when no wrist joint has a lever."""
    from payload_agent.evaluation.systematics import cable_spring, offsets, wrist

    sweeps, groups = list(sweeps), list(groups)
    aug, names = wrist.columns(sweeps, groups, theta, nuisance_gains=False)  # the run's, no scatter found
    M, joints = cable_spring.levers(sweeps, groups, names, mount_rad) if names else (None, ())
    if not joints:
        return None
    k, p = len(names), len(joints)
    spring = [dataclasses.replace(g, Y=np.hstack([g.Y[:, :4], g.Y[:, 4:4 + k] @ M])) for g in aug]
    spring, arm = offsets.augment(sweeps, spring, cable_spring.moving_arm_joint)  # as the run fits it (``fit_spring``)
    Ya = np.vstack([g.Y for g in spring])
    inv_a = np.linalg.pinv((Ya * w[:, None]).T @ Ya)
    Y = np.vstack([g.Y for g in groups])
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)
    sens = offsets.offset_sensitivities(sweeps, groups, w, inv, offsets.wrist_joint)
    AM = np.column_stack([sens.get(lab, np.zeros(4)) for lab in names]) @ M
    if gain_rel_std is None:
        return AM, inflation ** 2 * inv_a[4:4 + p, 4:4 + p], [], []
    kappa = wls.gain_directions(spring, Ya, w, inv_a, np.concatenate([theta, np.zeros(p + len(arm))]), gain_rel_std)
    plain = wls.gain_directions(groups, Y, w, inv, theta, gain_rel_std)
    both = sorted(set(kappa) & set(plain))
    return (AM, inflation ** 2 * inv_a[4:4 + p, 4:4 + p], [kappa[j][4:4 + p] for j in both],
            [plain[j][:4] for j in both])
