"""The drives' current-to-torque constants, from the controller's own two target signals.

A UR controller streams, per joint, the current it commands (``target_current``, A) and the
torque its own model asks for (``target_moment``, N·m). Their ratio is the constant the
controller itself uses, so it can turn measured currents into torques without a calibration
payload. The target current carries the controller's friction feed-forward and the target
moment does not, so the fit per joint is

    target_moment = k · target_current + c0 + c1 · sign(q̇) + c2 · q̇

over every row of every recording given (one offset and friction set per recording: friction
changes with temperature between runs). Fitting the ratio alone makes k 8–14 % too small on a
real UR10e (the friction feed-forward leaks into it).

A joint whose target moment is mostly friction and noise (a wrist on a slow trajectory) gives
no usable constant: its ``determined`` flag is False, with the reason, and an analysis leaves
that joint's torques out unless a calibration or the robot YAML gives its gain. Standard
uncertainty: the larger of the fit's own σ and half the spread between recordings (the
constant must not depend on the run).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.errors import DataError

MIN_R2 = 0.99  # the model must explain the target moment this well
MAX_REL_STD = 0.03  # a constant known worse than this is not used
SOURCE = "controller (target_moment / target_current fit)"


@dataclass(frozen=True)
class TorqueConstants:
    """Per-joint constants (N·m/A), their standard uncertainty and whether each can be used."""

    k_nm_per_a: tuple[float, ...]
    std_nm_per_a: tuple[float, ...]
    determined: tuple[bool, ...]
    reasons: tuple[str, ...]  # "" for a determined joint, else why not
    r2: tuple[float, ...]
    source: str = SOURCE

    def to_json(self) -> dict:
        return {"source": self.source, "k_nm_per_a": list(self.k_nm_per_a), "std_nm_per_a": list(self.std_nm_per_a),
                "determined": list(self.determined), "reasons": list(self.reasons), "r2": list(self.r2)}


def _fit_joint(runs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[float, float, float, list[float]]:
    """(k, σ_k, R², per-run k) of one joint over several (target current, target moment, q̇) runs."""
    n_runs = len(runs)
    rows = sum(len(i) for i, _, _ in runs)
    X = np.zeros((rows, 1 + 3 * n_runs))
    y = np.zeros(rows)
    r0 = 0
    for r, (i, tau, qd) in enumerate(runs):
        sl = slice(r0, r0 + len(i))
        X[sl, 0], X[sl, 1 + 3 * r], X[sl, 2 + 3 * r], X[sl, 3 + 3 * r] = i, 1.0, np.sign(qd), qd
        y[sl] = tau
        r0 += len(i)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    k = float(coef[0])
    r2 = float(1 - resid.var() / y.var()) if y.var() > 0 else 0.0
    # the residuals are correlated in time: the σ of k uses the effective number of independent rows
    lag1 = float(np.corrcoef(resid[:-1], resid[1:])[0, 1]) if len(resid) > 2 and resid.std() > 0 else 0.0
    inflate = (1 + max(lag1, 0.0)) / max(1 - max(lag1, 0.0), 1e-3)
    try:
        cov = np.linalg.inv(X.T @ X) * resid.var() * inflate
        fit_std = float(np.sqrt(max(cov[0, 0], 0.0)))
    except np.linalg.LinAlgError:
        fit_std = float("inf")
    per_run = []
    for i, tau, qd in runs:
        Xr = np.column_stack([i, np.ones(len(i)), np.sign(qd), qd])
        per_run.append(float(np.linalg.lstsq(Xr, tau, rcond=None)[0][0]))
    spread = (max(per_run) - min(per_run)) / 2 if n_runs > 1 else 0.0
    return k, max(fit_std, spread), r2, per_run


def fit_torque_constants(runs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> TorqueConstants:
    """Constants from recordings given as (target current (n,6) A, target moment (n,6) N·m, q̇ (n,6) rad/s)."""
    if not runs:
        raise DataError("torque constants: no recording with target_current and target_moment")
    n_j = runs[0][0].shape[1]
    ks, stds, det, reasons, r2s = [], [], [], [], []
    for j in range(n_j):
        joint_runs = [(i[:, j], tau[:, j], qd[:, j]) for i, tau, qd in runs]
        if all(np.ptp(i) == 0 for i, _, _ in joint_runs):
            ks.append(float("nan")), stds.append(float("nan")), r2s.append(0.0), det.append(False)
            reasons.append("its target current never changes")
            continue
        k, std, r2, per_run = _fit_joint(joint_runs)
        why = ""
        if not k > 0:
            why = f"the fit gives k = {k:.3g} N·m/A (not positive)"
        elif r2 < MIN_R2:
            why = f"the model explains only {100 * r2:.1f} % of its target moment (needs {100 * MIN_R2:.0f} %)"
        elif std / k > MAX_REL_STD:
            why = f"k is known to ±{100 * std / k:.1f} % only (runs give " + ", ".join(f"{v:.3f}" for v in per_run) + ")"
        ks.append(k), stds.append(std), r2s.append(r2), det.append(not why), reasons.append(why)
    return TorqueConstants(tuple(ks), tuple(stds), tuple(det), tuple(reasons), tuple(r2s))
