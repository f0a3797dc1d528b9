"""The general fit with nuisance offsets: torques the payload's weight cannot explain, estimated alongside θ.

Two unmodelled torques are constant along a sweep while the payload's gravity torque is not:

- on the **moving joint**: friction the baseline and the two-direction average leave. The average
  of the up and down legs cancels every term odd in speed; a term even in speed survives, e.g. the
  direction asymmetry of Coulomb friction, ((1 + a) − (1 − a))/2 · F_c = a·F_c, which no longer
  cancels against the empty run when the friction level changed between the runs (a baseline
  recorded cold, a tool run warm; a friction drift). One offset per (combined sweep, moving joint);
- on the **wrist joints**: a tool cable or hose from the forearm to the tool acts as a spring on
  joints 4–6, constant while the wrist stands still (it does during every arm sweep, at the same
  angles in every sweep of a pose). One offset per (pose, wrist joint). ``evaluation.cable_check``
  tests whether these are there.

The payload torque along a 55° sweep varies like cos/sin of the link angle, so an offset is
separable from it; the price is a wider σ (the fit has fewer effective degrees of freedom). Fitting
the moving joint's offsets also makes the estimate sensitive to slow position-dependent torque
(gear ripple once per output turn), which then biases it (benchmarks: +4 g mean in the ripple-only
ablation); ``evaluation.systematics`` instead keeps the plain estimate and puts the offsets' plausible
size into σ (``offset_sensitivities``: how θ responds to each).
"""

from __future__ import annotations

import math

from dataclasses import dataclass, replace
from typing import Callable, Iterable

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import general
from payload_agent.solvers.fitted import FittedModel
from payload_agent.solvers.wls import FitResult, Group, fit
from payload_agent.types import SweepKey

WRIST_JOINTS = (3, 4, 5)  # 0-based

Selector = Callable[[Group, DeltaSweep], "str | None"]  # the offset's name for a group, None: no offset


def moving_joint(group: Group, sweep: DeltaSweep) -> str | None:
    """One offset per (sweep, moving joint): the rows of the joint that moves in this sweep."""
    return group.label if group.joint == sweep.moving else None


def wrist_joint(group: Group, sweep: DeltaSweep) -> str | None:
    """One offset per (pose, wrist joint 4–6) standing still: the wrist keeps its angles through every
    sweep of a pose, so a cable's torque is the same in all of them."""
    if group.joint in WRIST_JOINTS and group.joint != sweep.moving:
        return f"{sweep.key.pose}/j{group.joint + 1}"
    return None


@dataclass(frozen=True)
class OffsetFit:
    """θ = [m, m·c] and the offsets fitted with it."""

    result: FitResult  # over [θ (4), offsets (k)]
    labels: list[str]  # the offsets' group labels, in column order
    groups: list[Group]  # the augmented groups

    @property
    def theta(self) -> np.ndarray:
        return self.result.theta[:4]

    @property
    def offsets_nm(self) -> np.ndarray:
        return self.result.theta[4:]

    @property
    def offsets_cov(self) -> np.ndarray:
        return self.result.cov[4:, 4:]

    def wald(self) -> float:
        """χ² = bᵀ·Cov(b)⁻¹·b of the offsets (k degrees of freedom)."""
        b = self.offsets_nm
        if not len(b):
            return 0.0
        return float(b @ np.linalg.lstsq(self.offsets_cov, b, rcond=None)[0])


def plain_groups(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics,
                 model: FittedModel | None = None) -> tuple[list[DeltaSweep], list[Group]]:
    """The general fit's sweeps and rows: ``model``'s when given (built from the same deltas), else built here."""
    if model is not None:
        sweeps, groups = list(model.sweeps), list(model.groups)
    else:
        sweeps = general.select_sweeps(deltas)
        groups = general.build_groups(sweeps, kin) if sweeps else []
    if not sweeps:
        raise DataError("offsets: no sweep to solve with")
    return sweeps, groups


def augment(sweeps: list[DeltaSweep], groups: list[Group], *selectors: Selector) -> tuple[list[Group], list[str]]:
    """The groups with one indicator column per offset the selectors name (groups naming the same
    offset share its column)."""
    by_name = {d.key.name: d for d in sweeps}
    names: list[str] = []
    picks: list[list[int]] = []
    for g in groups:
        cols = []
        for sel in selectors:
            name = sel(g, by_name[g.sweep])
            if name is None:
                continue
            if name not in names:
                names.append(name)
            cols.append(names.index(name))
        picks.append(cols)
    out = []
    for g, cols in zip(groups, picks):
        extra = np.zeros((len(g.y), len(names)))
        extra[:, cols] = 1.0
        out.append(replace(g, Y=np.hstack([g.Y, extra])))
    return out, names


def fit_offsets(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *selectors: Selector,
                gain_rel_std: Iterable[float] | None = None, model: FittedModel | None = None) -> OffsetFit:
    """The general fit with the offsets ``selectors`` name. With ``model`` (the analysis' fitted model of
    these deltas, whose drive-gain uncertainty it uses instead of ``gain_rel_std``), made once per model."""
    if model is not None:
        return model.cached(("offsets", selectors), lambda: _fit_offsets(*plain_groups(deltas, kin, model), selectors,
                                                                         model.gain_rel_std))
    return _fit_offsets(*plain_groups(deltas, kin), selectors, gain_rel_std)


def _fit_offsets(sweeps: list[DeltaSweep], groups: list[Group], selectors: tuple[Selector, ...],
                 gain_rel_std: Iterable[float] | None) -> OffsetFit:
    aug, labels = augment(sweeps, groups, *selectors)
    return OffsetFit(fit(aug, None if gain_rel_std is None else list(gain_rel_std)), labels, aug)


# -- how θ responds to constant torques ------------------------------------------------------------------

def offset_sensitivities(sweeps: list[DeltaSweep], groups: list[Group], w: np.ndarray, inv: np.ndarray,
                         selector: Selector) -> dict[str, np.ndarray]:
    """∂θ/∂b_k of a constant torque b_k on the rows ``selector`` names k: s_k = (YᵀWY)⁻¹·YᵀW·1_k.

    ``w``, ``inv``: the row weights and normal inverse of the fit of ``groups``; θ moves by Σ_k s_k·b_k.
    """
    by_name = {d.key.name: d for d in sweeps}
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    s: dict[str, np.ndarray] = {}
    for i, g in enumerate(groups):
        name = selector(g, by_name[g.sweep])
        if name is not None:
            s[name] = s.get(name, 0.0) + inv @ (g.Y.T @ w[starts[i]:starts[i + 1]])
    return s


def shrink(A: np.ndarray, b: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """(s, q) of measured effects b̂ (covariance ``cov``) as they move θ by β̂ = A·b̂: s² = max(q − r, 0)/q, the share
    of β̂ the data show beyond their noise, with q = β̂ᵀD⁻¹β̂, D = A·C·Aᵀ, r = rank D. E[q] = r + βᵀD⁻¹β (noncentral
    χ², docs/sources.md), so q − r is the unbiased size; the likelihood's q − 1 put 2–3 g into σ of clean runs whose
    noise was 1.5 g (issue 22)."""
    beta = A @ b
    D = A @ cov @ A.T
    q = float(beta @ np.linalg.lstsq(D, beta, rcond=None)[0]) if np.any(beta) else 0.0
    r = int(np.linalg.matrix_rank(D))
    return (math.sqrt(max(q - r, 0.0) / q) if q > 0 else 0.0), q


__all__ = ["WRIST_JOINTS", "Selector", "moving_joint", "wrist_joint", "OffsetFit", "plain_groups", "augment",
           "fit_offsets", "offset_sensitivities", "shrink"]
