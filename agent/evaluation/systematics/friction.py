"""What a run's two legs show about friction: its level, split into a constant and a load-dependent part.

At the same angle of the moving joint, gravity is the same in the up and the down leg while friction
odd in speed flips, so half the up − down effort gap is the friction level there. On an arm whose
friction is τ_f = s·[C + V·|q̇| + L·|τ_load|] (Coulomb, viscous, a Coulomb part growing with the load
torque, all scaled by a level s that drifts and changes with temperature) the gap along a constant-speed
sweep is

    gap(q) = s·(C + V·|q̇|) + s·L·|τ_load(q)|,

affine in |τ_load|, which the two legs' mean gives (the gravity torque at that angle). A regression of the
gap on [1, |mean|] along each sweep separates the constant part c₀ = s·(C + V·|q̇|) from the load-dependent
one. Why it matters (``systematics.friction_terms``): a Coulomb direction asymmetry a leaves a·s·C in the
two-direction average, which cancels against the empty run only if s did not change; the residual is
a·Δc₀ (a·Δs·C, plus a·Δs·V·|q̇| as a margin). The net change of the whole gap between the runs is no
measure of it: the loaded run's larger load torque raises the load-dependent part (symmetric, it cancels
in the average) and can hide a Coulomb drop behind it, or show a change where there is none.

Where a sweep's load torque varies too little to separate the two parts (a short sweep near the
horizontal), c₀'s uncertainty is large; ``coulomb_change`` then falls back on the declared prior.

The asymmetry acts on the Coulomb part s·C alone (``robot.friction_asymmetry_percent`` is "of the Coulomb
level"), and c₀ also holds the viscous part at the sweep speed: on the EC66 at a 10 % sweep V·|q̇| is half of C, so
a·Δc₀ overstated the residual 1.4–1.5× (issue 22, session 16). The legs' acceleration and braking ramps show the
gap at speeds from near rest to the sweep speed, at matching angles in both legs (the up leg starts where the down
leg stops), so a regression of the gap over the whole legs on [1, |q̇|, |mean|] splits the Coulomb part (the
intercept at zero speed and zero load) from the viscous one (``FrictionGap.coulomb_nm``), and ``coulomb_change``
pools its change. Samples slower than ``RAMP_MIN_SPEED_SHARE`` of the top speed are left out (stiction and the
Stribeck rise near rest are not in the affine model). Where the legs' speeds do not span enough of the range to
split them (a recording cut to the constant-speed windows), or where the split costs more precision than the
viscous part's plausible change (slow sweeps, ``coulomb_change``), c₀ stays the measure, the viscous part a margin.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from payload_agent.errors import DataError
from payload_agent.recording.rundata import SweepData
from payload_agent.types import SweepKey

MIN_SAMPLES = 10
RAMP_MIN_SPEED_SHARE = 0.1  # leg samples slower than this share of the leg's top speed: not in the speed split
MIN_SPEED_SPREAD = 0.3  # the used samples' speeds span at least this share of the top speed, or no speed split


@dataclass(frozen=True)
class FrictionGap:
    """One sweep's friction as its two legs show it (N·m), each part with its standard uncertainty."""

    level_nm: float  # median half-gap, in the up leg's direction of motion: positive when friction opposes motion
    std_nm: float  # of the median (noise, autocorrelation-corrected)
    constant_nm: float  # c₀: the part independent of the load torque (Coulomb + viscous at the sweep speed)
    constant_std_nm: float  # inf when the sweep's load torque varies too little to separate it
    load_slope: float  # s·L: the gap's growth per N·m of load torque
    # s·C: the Coulomb part alone (the intercept at zero speed and zero load over the whole legs, ramps included),
    # what a direction asymmetry multiplies; std inf where the legs' speeds vary too little to split it off
    coulomb_nm: float = float("nan")
    coulomb_std_nm: float = float("inf")
    viscous_nm: float = 0.0  # s·V·|q̇| at the sweep's top speed, from the same split (0 where not split)

    @property
    def coulomb_split(self) -> bool:
        return bool(np.isfinite(self.coulomb_std_nm))


def _legs(up: SweepData, down: SweepData, j: int, commands: Mapping, key: SweepKey, dkey: SweepKey
          ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(half-gap, mean of the legs, the up leg's direction) at the up leg's constant-speed angles inside the down leg's."""
    from payload_agent.analysis.delta import window_of

    try:
        wu, wd = window_of(up, commands.get(key)), window_of(down, commands.get(dkey))
    except DataError:
        return None
    xu, tu = up.q[wu.slice, j], up.effort_nm[wu.slice, j]
    xd, td = down.q[wd.slice, j], down.effort_nm[wd.slice, j]
    order = np.argsort(xd)
    inside = (xu >= xd[order][0]) & (xu <= xd[order][-1])
    if inside.sum() < MIN_SAMPLES:
        return None
    td_at = np.interp(xu[inside], xd[order], td[order])
    sign = 1.0 if xu[-1] >= xu[0] else -1.0
    return 0.5 * sign * (tu[inside] - td_at), 0.5 * (tu[inside] + td_at), sign


def _whole_legs(up: SweepData, down: SweepData, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(half-gap, mean of the legs, mean of the legs' speeds) over the whole legs, ramps included, at the up leg's
    angles inside the down leg's where both legs move faster than ``RAMP_MIN_SPEED_SHARE`` of their top speed."""
    qu, qd = up.q[:, j], down.q[:, j]
    if len(qu) < MIN_SAMPLES or len(qd) < MIN_SAMPLES:
        return None
    vu, vd = np.abs(np.gradient(qu, up.t)), np.abs(np.gradient(qd, down.t))
    order = np.argsort(qd)
    inside = (qu >= qd[order][0]) & (qu <= qd[order][-1])
    x = qu[inside]
    td_at, vd_at = np.interp(x, qd[order], down.effort_nm[order, j]), np.interp(x, qd[order], vd[order])
    top = min(float(np.max(vu)), float(np.max(vd)))
    keep = (vu[inside] > RAMP_MIN_SPEED_SHARE * top) & (vd_at > RAMP_MIN_SPEED_SHARE * top)
    if keep.sum() < MIN_SAMPLES:
        return None
    sign = 1.0 if qu[-1] >= qu[0] else -1.0
    tu = up.effort_nm[inside, j]
    return (0.5 * sign * (tu - td_at))[keep], (0.5 * (tu + td_at))[keep], (0.5 * (vu[inside] + vd_at))[keep]


def _split_speed(gap: np.ndarray, mean: np.ndarray, speed: np.ndarray) -> tuple[float, float, float]:
    """(s·C, its std, s·V at the top speed) of gap = s·C + s·V·|q̇| + s·L·|mean| (least squares, autocorrelation-corrected); std inf where
    the speeds span less than ``MIN_SPEED_SPREAD`` of the top speed (no ramps in the recording)."""
    from payload_agent.solvers.wls import autocorrelation_time

    if float(np.ptp(speed)) < MIN_SPEED_SPREAD * float(np.max(speed)):
        return float("nan"), float("inf"), 0.0
    A = np.column_stack([np.ones(len(gap)), speed, np.abs(mean)])
    AtA = A.T @ A
    if np.linalg.cond(AtA) > 1e12:
        return float("nan"), float("inf"), 0.0
    coef = np.linalg.solve(AtA, A.T @ gap)
    r = gap - A @ coef
    tau = autocorrelation_time(r)[0]
    var = float(r @ r) / max(len(r) - 3, 1) * max(tau, 1.0)
    return float(coef[0]), float(np.sqrt(var * np.linalg.inv(AtA)[0, 0])), float(coef[1] * np.max(speed))


def _split(gap: np.ndarray, mean: np.ndarray) -> tuple[float, float, float]:
    """(c₀, its std, slope) of gap = c₀ + slope·|mean| (least squares, autocorrelation-corrected)."""
    from payload_agent.solvers.wls import autocorrelation_time

    A = np.column_stack([np.ones(len(gap)), np.abs(mean)])
    AtA = A.T @ A
    if np.linalg.cond(AtA) > 1e12:
        return float(np.median(gap)), float("inf"), 0.0
    coef = np.linalg.solve(AtA, A.T @ gap)
    r = gap - A @ coef
    tau = autocorrelation_time(r)[0]
    var = float(r @ r) / max(len(r) - 2, 1) * max(tau, 1.0)
    return float(coef[0]), float(np.sqrt(var * np.linalg.inv(AtA)[0, 0])), float(coef[1])


def friction_gaps(sweeps: Mapping[SweepKey, SweepData], commands: Mapping | None = None
                  ) -> dict[tuple[str, int], FrictionGap]:
    """Per (pose, moving joint 0-based): the friction one run shows (of the joint's sweeps in that pose, the one
    with the largest level). ``commands`` (the plan's, ``segmenter.sweep_commands``) place the constant-speed
    windows as the subtraction does."""
    from payload_agent.solvers.wls import autocorrelation_time

    commands = commands or {}
    out: dict[tuple[str, int], FrictionGap] = {}
    for key, up in sweeps.items():
        if key.direction != "up":
            continue
        dkey = SweepKey(key.pose, key.joint, "down", key.speed_percent)
        if dkey not in sweeps:
            continue
        j = key.joint - 1
        legs = _legs(up, sweeps[dkey], j, commands, key, dkey)
        if legs is None:
            continue
        gap, mean, _ = legs
        med = float(np.median(gap))
        tau = autocorrelation_time(gap - med)[0]
        std = 1.2533 * float(np.std(gap)) * np.sqrt(max(tau, 1.0) / len(gap))  # median of ~normal noise
        c0, c0_std, slope = _split(gap, mean)
        whole = _whole_legs(up, sweeps[dkey], j)
        coulomb, coulomb_std, viscous = _split_speed(*whole) if whole is not None else (float("nan"), float("inf"), 0.0)
        found = FrictionGap(med, std, c0, c0_std, slope, coulomb, coulomb_std, viscous)
        if (key.pose, j) not in out or abs(found.level_nm) > abs(out[(key.pose, j)].level_nm):
            out[(key.pose, j)] = found
    return out


@dataclass(frozen=True)
class CoulombChange:
    """One joint's change of the constant friction part between the empty and the loaded run (N·m)."""

    measured_nm: float  # pooled over the joint's sweeps (inverse-variance); 0 with no usable sweep
    measured_std_nm: float  # inf: the data cannot tell
    prior_std_nm: float  # the declared change (``robot.friction_change_percent`` × the baseline's level)
    mean_nm: float  # the measurement and the prior combined (normal-normal)
    std_nm: float
    # True: the change of the Coulomb part alone (split from the viscous part by the legs' ramps); False: of the
    # constant part c₀ (Coulomb + viscous at the sweep speed, the viscous part a margin)
    coulomb_only: bool = False

    @property
    def rms_nm(self) -> float:
        """√E[Δ²]: what a direction asymmetry multiplies."""
        return float(np.hypot(self.mean_nm, self.std_nm))

    @property
    def measured(self) -> bool:
        """True when the data, not the prior, decide (the measurement at least as precise as the prior)."""
        return bool(np.isfinite(self.measured_std_nm)
                    and (self.prior_std_nm <= 0.0 or self.measured_std_nm <= self.prior_std_nm))


def _pooled(d: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """Inverse-variance mean of the finite entries and its variance ((0, inf) with none)."""
    ok = np.isfinite(v) & (v > 0)
    if not ok.any():
        return 0.0, float("inf")
    w = 1.0 / v[ok]
    return float(np.sum(w * d[ok]) / np.sum(w)), float(1.0 / np.sum(w))


def coulomb_change(loaded: list[FrictionGap], empty: list[FrictionGap], prior_std_nm: float,
                   change_rel: float | None = None) -> CoulombChange:
    """The change of the part a direction asymmetry acts on, of one joint, from its sweeps' gaps in both runs
    (``loaded[i]`` and ``empty[i]`` the same sweep), combined with the declared prior N(0, prior_std_nm²).

    Two measures: the Coulomb part's change, where every sweep of both runs split it from the viscous part, and the
    constant part's (Coulomb + viscous at the sweep speed), more precise but off by the viscous part's change. The
    Coulomb part's is used where its variance is below the constant part's plus the square of that possible offset,
    ``change_rel`` (the declared relative change) × the baseline's viscous part at the sweep speed: at a 10 % sweep
    of the EC66 the viscous part is half the Coulomb part, at 1 % a twentieth, where the split only adds noise
    (the intercept then extrapolates from short ramps). ``change_rel`` None: the Coulomb part's wherever split."""
    d0 = np.array([lo.constant_nm - em.constant_nm for lo, em in zip(loaded, empty)], float)
    v0 = np.array([lo.constant_std_nm ** 2 + em.constant_std_nm ** 2 for lo, em in zip(loaded, empty)], float)
    meas, meas_var = _pooled(d0, v0)
    coulomb = False
    if loaded and all(g.coulomb_split for g in (*loaded, *empty)):
        dc = np.array([lo.coulomb_nm - em.coulomb_nm for lo, em in zip(loaded, empty)], float)
        vc = np.array([lo.coulomb_std_nm ** 2 + em.coulomb_std_nm ** 2 for lo, em in zip(loaded, empty)], float)
        meas_c, var_c = _pooled(dc, vc)
        offset = 0.0 if change_rel is None else float(change_rel) * max(abs(g.viscous_nm) for g in empty)
        if change_rel is None or var_c < meas_var + offset ** 2:
            meas, meas_var, coulomb = meas_c, var_c, True
    prior_var = float(prior_std_nm) ** 2
    if prior_var <= 0.0:
        mean, var = (meas, meas_var) if np.isfinite(meas_var) else (0.0, 0.0)
    elif not np.isfinite(meas_var):
        mean, var = 0.0, prior_var
    else:
        var = 1.0 / (1.0 / meas_var + 1.0 / prior_var)
        mean = var * meas / meas_var
    return CoulombChange(meas, float(np.sqrt(meas_var)), float(prior_std_nm), float(mean), float(np.sqrt(var)),
                         coulomb)


def constant_level(gaps: list[FrictionGap]) -> float:
    """The largest constant part |c₀| of these gaps that the data split from the load-dependent part (N·m), else
    the largest level: the scale of the declared change's prior for the part a direction asymmetry multiplies
    (Coulomb, with the viscous part at the sweep speed as a margin: a loose prior lets the measured change decide),
    without the load-dependent part that the arm's own weight adds to the level."""
    split = [abs(g.constant_nm) for g in gaps if np.isfinite(g.constant_std_nm)]
    return max(split) if split else max(abs(g.level_nm) for g in gaps)


__all__ = ["FrictionGap", "friction_gaps", "CoulombChange", "coulomb_change", "constant_level"]
