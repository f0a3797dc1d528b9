"""The statistics of `verify`: does the mounted tool's torque match the library entry's, at matching angles?

Data: short joint sweeps, both directions, inside the stored empty-flange baseline's sweeps (same pose,
joint, speed), so the baseline's samples lie at the same joint angles. Per sweep the constant-speed
window is cut into angle bins; in each bin, per loaded joint j, the measured payload torque is

    Δτ_j = ½ [(mean τ_verify,up − mean τ_baseline,up) + (mean τ_verify,down − mean τ_baseline,down)]

(the two directions averaged: every friction term odd in velocity cancels, as in the identification),
with variance σ_j²/4 · (1/n_vu + 1/n_bu + 1/n_vd + 1/n_bd), σ_j the effort noise measured on the
baseline itself (residual of a cubic in the sweep angle, per sweep and joint, pooled apart for a joint
that sweeps and one that stands: ``EffortNoise``).

Model: Δτ = Y(q)·θ, θ = [m, m·cx, m·cy, m·cz] (``solvers.regressor.regressors``: static gravity plus the
centripetal load of the constant-speed sweep). With the expected tool θ₀ the residual r = Δτ − Y·θ₀ is
fitted by weighted least squares, δθ̂ = (YᵀWY)⁻¹YᵀW r, and the GLRT statistic

    T = δθ̂ᵀ (S_fit + S₀)⁻¹ δθ̂ ~ χ²₄ under "the tool matches"

(S_fit = (YᵀWY)⁻¹, scaled up by the fit's reduced χ² when that exceeds 1; S₀ the library entry's own
uncertainty). The tool is declared a mismatch when T > χ²₄(1 − α), α = 1 %: the false-alarm rate.
The detection limit is the non-centrality λ* at which the test has 95 % power; a mass error of ε·m
(same centre of mass) is found with that power when ε ≥ √(λ*/θ₀ᵀS⁻¹θ₀), a centre-of-mass shift d along
flange axis i when |d| ≥ √(λ*/(m²·S⁻¹ᵢᵢ)). The same formulas on the baseline's own samples predict
the limits before anything moves (``design_from_baseline``), which is how a verify motion is chosen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy import optimize, stats

from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.recording.rundata import SweepData
from payload_agent.solvers.regressor import regressors
from payload_agent.types import SweepKey

ALPHA = 0.01  # false-alarm rate
POWER = 0.95  # power at the stated detection limit
DOF = 4
LOADED_JOINTS = (1, 2, 3, 4, 5)  # 0-based: every joint but the vertical base joint carries the payload's weight
BIN_RAD = math.radians(0.5)
MIN_PER_BIN = 2
EDGE_MARGIN_RAD = math.radians(0.5)  # beyond the ramp: the controller's own smoothing at the ends of a move


def threshold(alpha: float = ALPHA, dof: int = DOF) -> float:
    return float(stats.chi2.ppf(1.0 - alpha, dof))


def critical_noncentrality(alpha: float = ALPHA, power: float = POWER, dof: int = DOF) -> float:
    """λ* with P(χ'²(dof, λ*) > threshold) = power."""
    t = threshold(alpha, dof)
    return float(optimize.brentq(lambda lam: stats.ncx2.sf(t, dof, lam) - power, 1e-6, 1e4))


@dataclass(frozen=True)
class Window:
    """The constant-speed angle interval of one sweep (moving joint, radians)."""

    low_rad: float
    high_rad: float


def cruise_window(start_rad: float, end_rad: float, speed_rad_s: float, accel_rad_s2: float) -> Window:
    """Where a trapezoidal PTP move from ``start`` to ``end`` (its leading joint) runs at constant speed."""
    ramp = speed_rad_s ** 2 / (2.0 * accel_rad_s2) + EDGE_MARGIN_RAD
    lo, hi = min(start_rad, end_rad) + ramp, max(start_rad, end_rad) - ramp
    if hi <= lo:
        raise DataError(f"a sweep of {math.degrees(abs(end_rad - start_rad)):.1f}° never reaches constant speed")
    return Window(lo, hi)


@dataclass(frozen=True)
class EffortNoise:
    """Per-joint effort noise σ (N·m) of the baseline, apart for a joint while it sweeps and while it stands.

    A drive is noisier in motion than holding still (the UR's 2-5×, docs/sources.md "Effort noise of the
    simulated UR5e"); one σ pooled over both weighted a verify bin of the sweeping joint as if quieter than it
    is and the standing joints' bins, which carry the payload's torque too, as if noisier (sim-ur5e joint 2:
    1.53 N·m pooled against 2.11 sweeping and 0.46 standing; issue 22, session 22)."""

    moving: np.ndarray  # (6,) each joint's σ in the sweeps that turn it
    standing: np.ndarray  # (6,) ... in the sweeps of the other joints

    def for_sweep(self, joint0: int) -> np.ndarray:
        """(6,) σ of every joint during a sweep of 0-based joint ``joint0``."""
        out = self.standing.copy()
        out[joint0] = self.moving[joint0]
        return out

    def describe(self) -> str:
        return (f"sweeping [{', '.join(f'{s:.3f}' for s in self.moving[1:])}], standing "
                f"[{', '.join(f'{s:.3f}' for s in self.standing[1:])}] N·m (joints 2-6)")


def noise_std(baseline: Mapping[SweepKey, SweepData], apart: bool = True) -> EffortNoise:
    """The baseline's effort noise (``EffortNoise``): residual of a cubic in the moving joint's angle, over the
    middle 80 % of every sweep's angle range, pooled with the fit's degrees of freedom over the sweeps where a
    joint moves, and apart over those where it stands. A joint that never did one of the two takes the other.
    ``apart`` False: one σ per joint over all sweeps, as before session 22 (``benchmarks.verify_power``'s
    comparison).

    The range, not the samples' percentiles: a sweep's file also holds the samples of the arm standing at
    its ends before and after the move, as many as the command came late (a loaded host: 137 in one sweep
    against a usual 5-25), and percentiles of those put the acceleration ramp, whose inertial torque no cubic
    follows, inside the fit (σ of joint 2 measured 0.80 N·m instead of 0.30 on the simulated EC66)."""
    ss, dof = np.zeros((2, 6)), np.zeros((2, 6))  # row 0: the joint sweeps, row 1: it stands
    for key, sweep in baseline.items():
        x = sweep.q[:, key.joint - 1]
        lo, hi = x.min() + 0.1 * np.ptp(x), x.max() - 0.1 * np.ptp(x)
        inside = (x >= lo) & (x <= hi)
        if inside.sum() < 20:
            continue
        xs = x[inside]
        A = np.vander((xs - xs.mean()) / max(np.ptp(xs), 1e-9), 4)
        coef, *_ = np.linalg.lstsq(A, sweep.effort_nm[inside], rcond=None)
        moving = np.arange(6) == key.joint - 1
        ss[np.where(moving, 0, 1), np.arange(6)] += ((sweep.effort_nm[inside] - A @ coef) ** 2).sum(axis=0)
        dof[np.where(moving, 0, 1), np.arange(6)] += int(inside.sum()) - 4
    if not dof.any():
        raise DataError("the stored baseline has too few samples to measure the effort noise")
    if not apart:
        pooled = np.sqrt(ss.sum(axis=0) / dof.sum(axis=0))
        return EffortNoise(pooled, pooled.copy())
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.sqrt(ss / dof)
    moving = np.where(dof[0] > 0, sigma[0], sigma[1])
    standing = np.where(dof[1] > 0, sigma[1], moving)
    return EffortNoise(moving, standing)


@dataclass
class Bins:
    """Angle bins of every verified sweep pair: where, what was measured, and how well."""

    q: np.ndarray  # (n, 6) joint angles at the bins
    dtau: np.ndarray  # (n, len(LOADED_JOINTS)) payload torque, N·m (zeros for a prediction)
    var: np.ndarray  # (n, len(LOADED_JOINTS)) its variance
    moving: np.ndarray  # (n,) 0-based moving joint
    speed: np.ndarray  # (n,) rad/s


def _bin_stats(x: np.ndarray, values: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.digitize(x, edges) - 1
    nb = len(edges) - 1
    counts = np.bincount(idx[(idx >= 0) & (idx < nb)], minlength=nb).astype(float)
    sums = np.zeros((nb, values.shape[1]))
    ok = (idx >= 0) & (idx < nb)
    np.add.at(sums, idx[ok], values[ok])
    with np.errstate(invalid="ignore", divide="ignore"):
        return counts, sums / counts[:, None]


def make_bins(windows: Mapping[tuple[str, int], Window], baseline: Mapping[SweepKey, SweepData],
              sigma: EffortNoise, speed_rad_s: float,
              verify: Mapping[SweepKey, SweepData] | None = None) -> Bins:
    """Bins of every (pose, joint) in ``windows``; without ``verify``, the baseline's samples stand in for
    the verify run's (a prediction: Δτ = 0, the variance the real run will have)."""
    qs, dts, vs, mv, sp = [], [], [], [], []
    cols = list(LOADED_JOINTS)
    for (pose, joint), win in windows.items():
        j = joint - 1
        nb = max(1, int(round((win.high_rad - win.low_rad) / BIN_RAD)))
        edges = np.linspace(win.low_rad, win.high_rad, nb + 1)
        parts = {}
        for d in ("up", "down"):
            bkey = next((k for k in baseline if (k.pose, k.joint, k.direction) == (pose, joint, d)), None)
            if bkey is None:
                raise DataError(f"the stored baseline has no {pose}-j{joint}-{d} sweep to compare with")
            b = baseline[bkey]
            v = verify.get(bkey) if verify is not None else b
            if v is None:
                raise DataError(f"the verify run has no complete {bkey.name} sweep")
            nbc, bmean = _bin_stats(b.q[:, j], b.effort_nm[:, cols], edges)
            nvc, vmean = _bin_stats(v.q[:, j], v.effort_nm[:, cols], edges)
            _, qmean = _bin_stats(v.q[:, j], v.q, edges)
            parts[d] = (nbc, bmean, nvc, vmean, qmean)
        (nbu, bu, nvu, vu, qu), (nbd, bd, nvd, vd, qd) = parts["up"], parts["down"]
        ok = np.minimum.reduce([nbu, nvu, nbd, nvd]) >= MIN_PER_BIN
        if not ok.any():
            continue
        dt = 0.5 * ((vu - bu) + (vd - bd)) if verify is not None else np.zeros_like(bu)
        inv = 1 / nvu + 1 / nbu + 1 / nvd + 1 / nbd
        qs.append(0.5 * (qu + qd)[ok])
        dts.append(dt[ok])
        vs.append((0.25 * inv[:, None] * sigma.for_sweep(j)[cols][None, :] ** 2)[ok])
        mv.append(np.full(ok.sum(), j))
        sp.append(np.full(ok.sum(), speed_rad_s))
    if not qs:
        raise DataError("no angle bin holds samples of both directions of both runs: the verify sweeps and the "
                        "stored baseline do not overlap")
    return Bins(np.vstack(qs), np.vstack(dts), np.vstack(vs), np.concatenate(mv), np.concatenate(sp))


def design(bins: Bins, kin: Kinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Y stacked (n·k, 4), Δτ stacked, weights 1/var) with Y from the regressor at the bins' angles."""
    Ys = np.zeros((len(bins.q), len(LOADED_JOINTS), 4))
    for j in np.unique(bins.moving):
        sel = bins.moving == j
        Ys[sel] = regressors(kin, bins.q[sel], LOADED_JOINTS, int(j), float(bins.speed[sel][0]))
    return Ys.reshape(-1, 4), bins.dtau.reshape(-1), 1.0 / bins.var.reshape(-1)


def theta_of(mass_kg: float, cog_mm: Sequence[float]) -> np.ndarray:
    return np.array([mass_kg, *(mass_kg * c / 1000.0 for c in cog_mm)])


def theta_cov(mass_kg: float, cog_mm: Sequence[float], mass_std_kg: float | None,
              cog_std_mm: Sequence[float] | None) -> np.ndarray:
    """Covariance of θ from a library entry's standard uncertainties (their correlations are not stored)."""
    sm = mass_std_kg or 0.0
    sc = [s / 1000.0 for s in cog_std_mm] if cog_std_mm is not None else [0.0, 0.0, 0.0]
    c = [v / 1000.0 for v in cog_mm]
    return np.diag([sm ** 2, *((mass_kg * s) ** 2 + (ci * sm) ** 2 for s, ci in zip(sc, c))])


@dataclass(frozen=True)
class Limits:
    """The smallest errors the test finds with ``POWER`` at false-alarm rate ``ALPHA``."""

    mass_percent: float
    cog_mm: tuple[float, float, float]

    def meets(self, mass_percent: float, cog_mm: float) -> bool:
        return self.mass_percent <= mass_percent and max(self.cog_mm) <= cog_mm

    def describe(self) -> str:
        return (f"detects a mass error of {self.mass_percent:.2f} % or a centre-of-mass shift of "
                f"[{', '.join(f'{d:.1f}' for d in self.cog_mm)}] mm (x, y, z) with {100 * POWER:.0f} % power "
                f"at a {100 * ALPHA:g} % false-alarm rate")


def limits(S_inv: np.ndarray, theta0: np.ndarray) -> Limits:
    lam = critical_noncentrality()
    m = float(theta0[0])
    mass = math.sqrt(lam / max(float(theta0 @ S_inv @ theta0), 1e-300))
    cog = tuple(1000.0 * math.sqrt(lam / max(m * m * float(S_inv[i, i]), 1e-300)) for i in (1, 2, 3))
    return Limits(100.0 * mass, cog)  # type: ignore[arg-type]


def predict_limits(bins: Bins, kin: Kinematics, theta0: np.ndarray, S0: np.ndarray) -> Limits:
    Y, _, w = design(bins, kin)
    S_fit = np.linalg.pinv(Y.T @ (w[:, None] * Y))
    return limits(np.linalg.pinv(S_fit + S0), theta0)


@dataclass(frozen=True)
class TestResult:
    """The verdict with everything it rests on (SI inside, mm and % where named)."""

    matches: bool
    statistic: float
    threshold: float
    p_value: float
    mass_kg: float  # what the verify data say the mounted tool is (θ₀ + δθ̂)
    cog_mm: tuple[float, float, float]
    mass_diff_kg: float
    cog_diff_mm: tuple[float, float, float]
    mass_std_kg: float
    cog_std_mm: tuple[float, float, float]
    reduced_chi2: float
    limits: Limits
    bins: int

    def describe(self, expected: str) -> str:
        head = (f"MATCHES {expected}" if self.matches else f"DOES NOT MATCH {expected}")
        return (f"{head}: T = {self.statistic:.1f} against {self.threshold:.1f} (χ²₄ at {100 * ALPHA:g} %, "
                f"p = {self.p_value:.3g}); mounted tool measures {self.mass_kg:.3f} kg "
                f"({self.mass_diff_kg:+.3f} kg, ±{1.96 * self.mass_std_kg:.3f}), centre of mass "
                f"[{', '.join(f'{c:.1f}' for c in self.cog_mm)}] mm "
                f"([{', '.join(f'{d:+.1f}' for d in self.cog_diff_mm)}] mm, "
                f"±[{', '.join(f'{1.96 * s:.1f}' for s in self.cog_std_mm)}]); the test "
                + self.limits.describe())

    def to_json(self) -> dict:
        return {"matches": self.matches, "statistic": self.statistic, "threshold": self.threshold,
                "p_value": self.p_value, "mass_kg": self.mass_kg, "cog_mm": list(self.cog_mm),
                "mass_diff_kg": self.mass_diff_kg, "cog_diff_mm": list(self.cog_diff_mm),
                "mass_std_kg": self.mass_std_kg, "cog_std_mm": list(self.cog_std_mm),
                "reduced_chi2": self.reduced_chi2, "bins": self.bins, "alpha": ALPHA, "power": POWER,
                "detection_limit": {"mass_percent": self.limits.mass_percent, "cog_mm": list(self.limits.cog_mm)}}


def glrt(bins: Bins, kin: Kinematics, theta0: np.ndarray, S0: np.ndarray) -> TestResult:
    """The GLRT of the module docstring on measured bins."""
    Y, dtau, w = design(bins, kin)
    r = dtau - Y @ theta0
    A = Y.T @ (w[:, None] * Y)
    S_fit = np.linalg.pinv(A)
    dtheta = S_fit @ (Y.T @ (w * r))
    resid = r - Y @ dtheta
    dof = max(1, len(r) - DOF)
    red = float((w * resid ** 2).sum() / dof)
    S_fit = S_fit * max(1.0, red)  # data noisier than the baseline said: widen, never narrow
    S = S_fit + S0
    S_inv = np.linalg.pinv(S)
    T = float(dtheta @ S_inv @ dtheta)
    thr = threshold()
    theta = theta0 + dtheta
    m = float(theta[0])
    cog = theta[1:] / m
    # delta method for c = (m c)/m
    J = np.zeros((3, 4))
    J[:, 0] = -theta[1:] / m ** 2
    J[:, 1:] = np.eye(3) / m
    cog_std = np.sqrt(np.clip(np.diag(J @ S_fit @ J.T), 0, None))
    cog0 = theta0[1:] / theta0[0]
    return TestResult(T <= thr, T, thr, float(stats.chi2.sf(T, DOF)), m, tuple(1000 * cog),
                      m - float(theta0[0]), tuple(1000 * (cog - cog0)), float(math.sqrt(max(S_fit[0, 0], 0.0))),
                      tuple(1000 * cog_std), red, limits(S_inv, theta0), len(bins.q))  # type: ignore[arg-type]


def fit_theta(bins: Bins, kin: Kinematics) -> tuple[np.ndarray, np.ndarray]:
    """θ and its covariance by weighted least squares on bins (the benchmark's stand-in for a library entry
    identified with the same model: a full sweep's bins give what `run` would store, biases included)."""
    Y, dtau, w = design(bins, kin)
    A = Y.T @ (w[:, None] * Y)
    cov = np.linalg.pinv(A)
    theta = cov @ (Y.T @ (w * dtau))
    red = float((w * (dtau - Y @ theta) ** 2).sum() / max(1, len(dtau) - DOF))
    return theta, cov * max(1.0, red)
