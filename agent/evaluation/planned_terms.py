"""The data-sized systematic terms of a run, predicted before it (for ``evaluation.design``).

``systematics.planned_covariance`` predicts the terms fixed by declarations (joint zeros). Two terms of a
run are sized from its own data, and ``plan --target-std`` has to predict what the run will report
(issue 22: a plan that leaves them out picks a procedure whose reported σ then misses the target):

- **wrist torques**: a run whose manifest records where the loaded phase started (every run of the product: it
  starts where the run's own empty run ended, the plan's last pose, and the tool goes on there) fits a tool
  cable's spring relaxed there (``systematics.cable_spring``): stiffnesses κ̂ (covariance C) move θ by AM·κ; the
  run projects κ̂ onto κ ≥ 0, tests its presence and puts β̂β̂ᵀ + D into σ where it finds a cable, w·β̂β̂ᵀ below the
  test (``cable_spring.shares``); where the robot YAML declares a cable (``robot.tool_cable_fitted``) the run takes
  AM·κ̂ off θ̂ and σ holds κ̂'s noise through AM and the drive gains' response of the corrected θ̂ in every run
  (``cable_spring.term``), and so does the plan (``planned_spring.declared_spring_covariance``); where it declares none
  (``tool_cable_fitted: false``) the run carries the term only where its test finds a cable, and so do the plan's
  draws (``spring_model(absent=True)``). Without a recorded
  mount it fits
  free offsets b̂ (one per pose and wrist joint, ``systematics.wrist_terms``), β̂ = A·b̂, D = A·C·Aᵀ, shrunk by
  s² = max(q − r, 0)/q, q = β̂ᵀD⁻¹β̂, r = rank D; with no wrist torque its expectation is D·E[(χ²_r − r)⁺]/r
  (z's direction is uniform and independent of |z|²). Both with β̂'s true spread (``SPREAD_RATIO``: below), C
  computed here from the planned sweeps as the run computes it (drive-gain part included). Either term is 0
  in about two thirds of clean runs and large in the rest, so the plan draws it by the run's own rule
  (``WristModel``, ``reported_sigma_draws``: a seeded draw of the standard normals, the same for every
  candidate) and predicts the distribution of the σ the run reports, not one number (issue 22). A real cable
  adds to that; it is not predicted (the gate's cable check refuses strong ones).
- **residual friction** (``systematics.friction_terms``): asymmetry a (declared) × √E[Δ²], where the run's
  Δ combines the constant friction part's change it measures (precision v_m, from the split of each
  sweep's half gap into a constant and a load-proportional part, ``systematics.friction``) with the
  declared prior N(0, v_p). With k = v_p/(v_p + v_m) the run reports v_p·v_m/(v_p + v_m) + k²·(Δ² + v_m)
  on average, where Δ is the arm's true change. Its expectation under the prior is v_p (what the plan
  used before); when an earlier run of this robot with both phases (the calibration's, or an
  identification with its own empty run) measured Δ, E[Δ²] is that measurement's posterior
  (mean² + variance) instead. v_m here: noise of the half gap (σ²/2 per sample and run, both runs)
  and the regression on [1, |load torque|] along the planned sweep; the load torque's shape is the
  planned payload's on the moving joint (the arm's own gravity on joints 2/3 has nearly the same shape
  in the procedures' poses).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation.planned_spring import declared_spring_covariance, spring_covariance
from payload_agent.solvers import wls


# The true spread of the loaded-minus-empty torques against the 2σ² the plan (and, through its residuals and
# their autocorrelation, the run) assigns them: the empty run's samples are interpolated onto the loaded
# run's angles, which for a uniform fractional position t leaves E[(1 − t)² + t²]·σ² = ⅔σ² of its noise, so
# (1 + ⅔)/2 = ⅚. Offline seeded runs of sim-ec66 (16 seeds, paper_bd 15 %, 0–55°) gave a mean q of 3.1 for
# r = 4 (⅚·4 = 3.3).
SPREAD_RATIO = 5.0 / 6.0


def shrunk_share(rank: int, spread: float = SPREAD_RATIO) -> float:
    """E[(q − r)⁺/q · β̂β̂ᵀ] as a multiple of D, for β̂ ~ N(0, spread·D), q = β̂ᵀD⁻¹β̂ ~ spread·χ²_r: the expected
    share of D the wrist term keeps on an arm without wrist torques (z's direction is uniform, independent
    of |z|, so the expectation is E[(spread·X − r)⁺]/r · D with X ~ χ²_r)."""
    if rank <= 0:
        return 0.0
    from scipy.stats import chi2

    r, c = float(rank), float(rank) / spread
    # E[X·1{X > c}] = r·P(χ²_{r+2} > c) for X ~ χ²_r
    return (spread * r * float(chi2.sf(c, rank + 2)) - r * float(chi2.sf(c, rank))) / r


def wrist_spread(sweeps: Sequence[DeltaSweep], groups: Sequence[wls.Group], w: np.ndarray, inflation: float,
                 theta: np.ndarray, gain_rel_std: Sequence[float] | None) -> np.ndarray:
    """D = A·C·Aᵀ, the covariance of the wrist offsets' effect on θ a run of the planned sweeps fits (as the run
    computes it: offset sensitivities of the plain fit, the offsets' covariance of the fit with them)."""
    from payload_agent.evaluation.systematics import offsets

    sweeps, groups = list(sweeps), list(groups)
    aug, labels = offsets.augment(sweeps, groups, offsets.wrist_joint)
    if not labels:
        return np.zeros((4, 4))
    Y = np.vstack([g.Y for g in groups])
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)
    sens = offsets.offset_sensitivities(sweeps, groups, w, inv, offsets.wrist_joint)
    A = np.column_stack([sens.get(lab, np.zeros(4)) for lab in labels])
    cov_a = _augmented_covariance(aug, w, theta, len(labels), inflation, gain_rel_std)
    return A @ cov_a[4:, 4:] @ A.T


def _augmented_covariance(aug, w, theta, n_extra: int, inflation: float, gain_rel_std) -> np.ndarray:
    """The covariance of the fit with ``n_extra`` nuisance columns beside θ (noise scaled by ``inflation``, plus
    the drive gains' part where their uncertainty is known), as the run's own fit computes it."""
    Ya = np.vstack([g.Y for g in aug])
    inv_a = np.linalg.pinv((Ya * w[:, None]).T @ Ya)
    cov = inv_a * inflation ** 2
    if gain_rel_std is not None:
        cov = cov + wls.gain_covariance(aug, Ya, w, inv_a, np.concatenate([theta, np.zeros(n_extra)]), gain_rel_std)
    return cov


# the standard normal draws of β̂'s whitened coordinates that ``reported_sigma_draws`` uses for every candidate (the
# same draws for all: common random numbers, so two candidates' probabilities differ by their term, not by chance)
DRAWS, DRAW_SEED = 2000, 22
_Z: list[np.ndarray] = []


@dataclass(frozen=True)
class WristModel:
    """The wrist-torque term a run of the planned sweeps will fit, drawn by the run's own rule.

    Free offsets (``systematics.wrist``, ``spring`` False): β̂ ~ N(0, ratio·D), a·β̂β̂ᵀ in σ with the run's
    a = s² = (q − r)⁺/q. A tool cable's spring (``systematics.cable_spring``, ``spring`` True: the run knows
    where the tool was mounted): κ̂ ~ N(0, ratio·C), β̂ = AM·κ*, κ* its projection onto κ ≥ 0, and β̂β̂ᵀ in σ
    where its presence test finds a cable, w·β̂β̂ᵀ below it, w = (T − E₀[T])⁺/T (``cable_spring.shares``). Per draw
    the term is a·β̂β̂ᵀ + b·D (offsets: b = 0; spring: a = 1 where found, else w; b = 0 since session 18). C is the
    κ block of the run's spring fit, beside θ and the moving arm joints' offsets (``cable_spring.fit_spring``)."""

    spread: np.ndarray  # D (4, 4): A·C·Aᵀ of the offsets, or AM·C·AMᵀ of the spring
    spring: bool
    a: np.ndarray = dataclasses.field(compare=False, repr=False)  # (DRAWS,)
    beta: np.ndarray = dataclasses.field(compare=False, repr=False)  # (DRAWS, 4)
    b: np.ndarray = dataclasses.field(compare=False, repr=False)  # (DRAWS,)

    def over(self, runs: int) -> "WristModel":
        """The same term for ``runs`` repetitions averaged: covariances / runs, the run's a, b unchanged (q, T and the
        weight do not change with a common scale; κ* scales with κ̂)."""
        return dataclasses.replace(self, spread=self.spread / runs, beta=self.beta / math.sqrt(runs))

    def expected(self) -> np.ndarray:
        """The term's expected covariance (what ``covariance_terms`` names "wrist"): exact for the offsets
        (``shrunk_share``), the draws' mean for the spring."""
        if not self.spring:
            r = int(np.linalg.matrix_rank(self.spread)) if np.any(self.spread) else 0
            return shrunk_share(r) * self.spread
        return (self.a[:, None] * self.beta).T @ self.beta / len(self.a) + float(np.mean(self.b)) * self.spread


def offset_model(D: np.ndarray, ratio: float = SPREAD_RATIO) -> WristModel:
    """The free offsets' term of a run whose offsets' effect on θ has covariance D, drawn."""
    z_all = _normal_draws()
    r = int(np.linalg.matrix_rank(D)) if np.any(D) else 0
    if r == 0:
        return WristModel(D, False, np.zeros(DRAWS), np.zeros((DRAWS, 4)), np.zeros(DRAWS))
    lam, vec = np.linalg.eigh(0.5 * (D + D.T))
    lam, vec = np.clip(lam[-r:], 0.0, None), vec[:, -r:]  # the r largest: the rank the run counts
    z = z_all[:, :r]
    q = ratio * np.sum(z ** 2, axis=1)
    a = np.maximum(q - r, 0.0) / np.maximum(q, 1e-300)
    return WristModel(D, False, a, (z * np.sqrt(ratio * lam)) @ vec.T, np.zeros(DRAWS))


def spring_model(AM: np.ndarray, C: np.ndarray, ratio: float = SPREAD_RATIO, declared: bool = False,
                 absent: bool = False) -> WristModel:
    """The cable spring's term of a run whose stiffnesses κ̂ (covariance C) move θ by AM·κ, drawn. ``declared``
    (``robot.tool_cable_fitted: true``): the run's σ holds the correction's noise D = AM·C·AMᵀ, the same in every run.
    ``absent`` (``robot.tool_cable_fitted: false``): the term only in the draws whose T exceeds the test's quantile
    (``CableSpring.weight``)."""
    from scipy.optimize import nnls

    from payload_agent.evaluation.systematics import cable_spring

    if declared:
        return declared_model(AM @ C @ AM.T)

    R = np.linalg.cholesky(np.linalg.inv(C)).T  # RᵀR = C⁻¹, as the run whitens
    u = np.sqrt(ratio) * _normal_draws()[:, :len(C)]  # R·κ̂
    T = cable_spring.statistics(R, u)
    critical, null_mean = cable_spring.null_distribution(C)
    below = 0.0 if absent else np.maximum(T - null_mean, 0.0) / np.maximum(T, 1e-300)
    weight = np.where(T > critical, 1.0, below)
    kappa = np.zeros_like(u)
    for i in np.flatnonzero(weight > 0):  # κ*: the run's projection (``cable_spring.project``) of κ̂ = R⁻¹·u
        kappa[i] = nnls(R, u[i])[0]
    a, b = cable_spring.shares(weight, T > critical)  # the run's own rule: a·β̂β̂ᵀ + b·D
    return WristModel(AM @ C @ AM.T, True, a, kappa @ AM.T, b)


def declared_model(D: np.ndarray) -> WristModel:
    """A declared cable's term (``robot.tool_cable_fitted``): the run's σ holds the correction's own covariance ``D``
    (``declared_spring_covariance``) whatever κ̂, the same in every draw."""
    return WristModel(D, True, np.zeros(DRAWS), np.zeros((DRAWS, 4)), np.ones(DRAWS))


def _normal_draws() -> np.ndarray:
    if not _Z:
        _Z.append(np.random.default_rng(DRAW_SEED).standard_normal((DRAWS, 4)))
    return _Z[0]


def wrist_model(sweeps: Sequence[DeltaSweep], groups: Sequence[wls.Group], w: np.ndarray, inflation: float,
                theta: np.ndarray, gain_rel_std: Sequence[float] | None,
                mount_rad: Sequence[float] | None = None, declared: bool = False, absent: bool = False) -> WristModel:
    """The wrist term of a run of the planned sweeps on an arm without wrist torques: the tool cable's spring
    relaxed at ``mount_rad`` (where the loaded run starts, as the run records it; ``declared``: the robot YAML
    declares a cable, ``cable_declared``; ``absent``: it declares none, ``cable_absent``), else the free offsets."""
    if mount_rad is None:
        return offset_model(wrist_spread(sweeps, groups, w, inflation, theta, gain_rel_std))
    if declared:
        D = declared_spring_covariance(sweeps, groups, w, inflation, theta, gain_rel_std, mount_rad)
        return offset_model(np.zeros((4, 4))) if D is None else declared_model(D)
    spring = spring_covariance(sweeps, groups, w, inflation, theta, gain_rel_std, mount_rad)
    if spring is None:  # no wrist joint with a lever: the run has no wrist term
        return offset_model(np.zeros((4, 4)))
    return spring_model(*spring, absent=absent)


def cable_declared(joints) -> bool:
    """Whether the robot's declarations (``JointSystematicsConfig`` or None) say a tool cable is fitted."""
    return getattr(joints, "tool_cable_fitted", None) is True


def cable_absent(joints) -> bool:
    """Whether the robot's declarations (``JointSystematicsConfig`` or None) say no cable or hose runs to the tool."""
    return getattr(joints, "tool_cable_fitted", None) is False


def reported_sigma_draws(base_cov: np.ndarray, model: WristModel, theta: np.ndarray, noise_cov: np.ndarray | None = None,
                         spread=None) -> tuple[np.ndarray, np.ndarray]:
    """(σ mass g, σ centre of mass mm, largest axis) a run of the candidate reports, one per seeded draw
    (``DRAWS``): the covariance ``base_cov`` (every other term) plus the wrist term by the run's own rule
    (``WristModel``). Its mean covariance is ``base_cov + model.expected()``, the root of which the plan predicted
    before (issue 22: the term is 0 in about two thirds of clean runs and large in the rest, so no single number
    of it is what a user sees). ``noise_cov``, the part of ``base_cov`` that is the noise term, scaled per draw by
    the run's own estimate of it (``spread``: ``noise_scatter.NoiseScatter``, mass and CoM; none: as planned)."""
    from payload_agent.solvers.wls import cog_with_covariance

    _, base_c = cog_with_covariance(theta, base_cov)
    J = np.zeros((3, 4))  # the delta method's Jacobian of c = θ[1:]/θ[0] (``cog_with_covariance``)
    J[:, 0], J[:, 1:] = -theta[1:] / theta[0] ** 2, np.eye(3) / theta[0]
    a, beta, b, D = model.a, model.beta, model.b, model.spread
    var_m = float(base_cov[0, 0]) + a * beta[:, 0] ** 2 + b * D[0, 0]
    var_c = np.diag(base_c)[None, :] + a[:, None] * (beta @ J.T) ** 2 + b[:, None] * np.diag(J @ D @ J.T)[None, :]
    if noise_cov is not None and spread is not None:
        f = spread.factors() - 1.0  # the run's noise variance over the plan's, minus 1
        var_m = var_m + f[:, 0] * float(noise_cov[0, 0])
        var_c = var_c + f[:, 1:2] * np.diag(J @ noise_cov @ J.T)[None, :]
    return (1000.0 * np.sqrt(np.maximum(var_m, 0.0)),
            1000.0 * np.sqrt(np.maximum(np.max(var_c, axis=1), 0.0)))


@dataclass(frozen=True)
class FrictionKnowledge:
    """What is known about each joint's change of the constant friction part between an empty and a loaded
    run (N·m): an earlier run's posterior, and where it came from."""

    mean_nm: Mapping[int, float]
    std_nm: Mapping[int, float]
    source: str

    def expected_square(self, joint: int) -> float | None:
        if joint not in self.mean_nm:
            return None
        return float(self.mean_nm[joint]) ** 2 + float(self.std_nm[joint]) ** 2


def measurement_variance(d: DeltaSweep, g: wls.Group, theta: np.ndarray, effort_std_nm: float,
                         inflation: float) -> float:
    """Variance of the constant part's change one combined sweep will measure (loaded and empty run)."""
    shape = np.abs(g.Y @ theta)
    A = np.column_stack([np.ones(len(shape)), shape])
    AtA = A.T @ A
    if len(shape) < 10 or np.linalg.cond(AtA) > 1e12:
        return float("inf")
    one_run = 0.5 * effort_std_nm ** 2 * inflation ** 2 * float(np.linalg.inv(AtA)[0, 0])
    return 2.0 * one_run


def expected_change_square(prior_var: float, meas_var: float, truth_square: float) -> float:
    """E[mean² + var] of the run's combination of its measurement (variance ``meas_var``) with the prior, for a
    true change of mean square ``truth_square``."""
    if prior_var <= 0.0:
        return 0.0 if not math.isfinite(meas_var) else truth_square + 2.0 * meas_var
    if not math.isfinite(meas_var):
        return prior_var
    k = prior_var / (prior_var + meas_var)
    return prior_var * meas_var / (prior_var + meas_var) + k * k * (truth_square + meas_var)


def friction_covariance(sweeps: Sequence[DeltaSweep], groups: Sequence[wls.Group], w: np.ndarray,
                        theta: np.ndarray, asymmetry: float, change_rel: float, level_nm: Mapping[int, float],
                        effort_std_nm: Sequence[float], inflation: float,
                        known: FrictionKnowledge | None = None) -> np.ndarray:
    """Expected covariance of the residual-friction term of a run of the planned sweeps."""
    from payload_agent.evaluation.systematics import offsets

    if asymmetry <= 0 or not level_nm:
        return np.zeros((4, 4))
    sweeps, groups = list(sweeps), list(groups)
    by_name = {d.key.name: d for d in sweeps}
    Y = np.vstack([g.Y for g in groups])
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)

    def per_joint(g: wls.Group, d: DeltaSweep) -> str | None:
        ok = g.joint == d.moving and d.key.direction == "both" and g.joint in level_nm
        return str(g.joint) if ok else None

    info: dict[int, float] = {}
    for g in groups:
        d = by_name[g.sweep]
        if per_joint(g, d) is None:
            continue
        v = measurement_variance(d, g, theta, float(effort_std_nm[g.joint]), inflation)
        info[g.joint] = info.get(g.joint, 0.0) + (0.0 if not math.isfinite(v) else 1.0 / v)
    cov = np.zeros((4, 4))
    for j, s in offsets.offset_sensitivities(sweeps, groups, w, inv, per_joint).items():
        j = int(j)
        prior_var = (change_rel * float(level_nm[j])) ** 2
        meas_var = 1.0 / info[j] if info.get(j, 0.0) > 0 else float("inf")
        truth = known.expected_square(j) if known is not None else None
        e2 = expected_change_square(prior_var, meas_var, prior_var if truth is None else truth)
        cov += asymmetry ** 2 * e2 * np.outer(s, s)
    return cov


def earlier_friction_change(config, limit: int = 5) -> FrictionKnowledge | None:
    """The friction change the newest earlier run of this robot with both phases measured (its own empty run:
    a calibration, or an identification with a fresh baseline), per joint, as the run's term combines it
    with the declared prior; None without one. Looks at the stored calibration's run and the newest ``limit``
    run folders."""
    from payload_agent.errors import DataError
    from payload_agent.evaluation.calibration import effective_calibration
    from payload_agent.evaluation.systematics import friction
    from payload_agent.analysis.run_deltas import phases_for

    decl = config.robot.joints
    if float(decl.friction_asymmetry_std) <= 0:
        return None
    runs = Path(config.storage.runs_dir)
    folders = sorted((p for p in runs.glob("*") if (p / "empty").is_dir() and (p / "loaded").is_dir()),
                     reverse=True)[:limit] if runs.is_dir() else []
    cal = effective_calibration(config)
    if cal is not None and Path(cal.run_dir).is_dir():
        folders.append(Path(cal.run_dir))
    gains = np.asarray(cal.gains_nm_per_unit if cal is not None else config.effort.gains_nm_per_unit, float)
    for folder in folders:
        try:
            loaded, empty, commands = phases_for(folder, gains)
        except (DataError, OSError, ValueError, KeyError):
            continue
        lo, em = friction.friction_gaps(loaded, commands), friction.friction_gaps(empty, commands)
        pairs = sorted(set(lo) & set(em))
        if not pairs:
            continue
        mean, std = {}, {}
        for j in sorted({j for _, j in pairs}):
            mine = [p for p in pairs if p[1] == j]
            level = max(abs(em[p].level_nm) for p in mine)
            c = friction.coulomb_change([lo[p] for p in mine], [em[p] for p in mine],
                                        float(decl.friction_change_std) * level)
            mean[j], std[j] = c.mean_nm, c.std_nm
        return FrictionKnowledge(mean, std, f"the friction change measured in {folder.name}")
    return None


__all__ = ["shrunk_share", "wrist_spread", "WristModel", "offset_model", "spring_model", "wrist_model", "cable_declared",
           "cable_absent",
           "spring_covariance", "reported_sigma_draws", "FrictionKnowledge", "measurement_variance", "expected_change_square",
           "friction_covariance", "earlier_friction_change"]
