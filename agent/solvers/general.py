"""The general solver: weighted least squares on Δτ = Y(q)·θ over every loaded joint and sweep.

θ = [m, m·cx, m·cy, m·cz] (c in the flange frame, SI). Rows come from every joint whose
regressor rows are not all zero (joint 1 has a vertical axis and never carries the
payload's weight) and from every constant-speed sample of every sweep. Where a
bidirectional sweep was combined (direction "both", see ``payload_agent.combine``) the
combined sweep replaces its "up" and "down" halves.

Weights: one unweighted fit, then the residual variance σ²(sweep, joint) of each group,
then the fit again with weights 1/σ². The covariance of θ is s²·(YᵀWY)⁻¹ with s² the
weighted residual variance per degree of freedom (≈ 1 after reweighting), which is the
least-squares (Cramér–Rao) covariance for independent Gaussian noise. Samples of one
sweep are in practice correlated through friction that did not cancel; the residual
RMS per sweep and joint is reported so that shows up.

The centre of mass c = (m·c)/m gets its covariance from the delta method.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from payload_agent.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.kinematics import Kinematics
from payload_agent.planner import SweepKey
from payload_agent.results import Estimate

NAME = "general"
GRAVITY_JOINTS = (1, 2, 3, 4, 5)  # 0-based: joints 2..6
ZERO_ROW_TOL = 1e-9  # N·m per unit θ: a joint whose rows are all below this carries no payload torque
SIGMA_FLOOR_NM = 1e-9  # noise-free data: keep the weights finite


@dataclass
class Group:
    """The rows of one (sweep, joint) pair."""

    label: str
    sweep: str
    Y: np.ndarray  # (n, 4)
    y: np.ndarray  # (n,)


def select_sweeps(deltas: dict[SweepKey, DeltaSweep], *, poses: Iterable[str] | None = None,
                  use_combined: bool = True) -> list[DeltaSweep]:
    """Combined sweeps where available, else every plain sweep; optionally only some poses."""
    wanted = None if poses is None else set(poses)
    chosen = [d for k, d in deltas.items() if wanted is None or k.pose in wanted]
    if use_combined:
        both = {(d.key.pose, d.key.joint, d.key.speed_percent) for d in chosen if d.key.direction == "both"}
        chosen = [d for d in chosen
                  if d.key.direction == "both" or (d.key.pose, d.key.joint, d.key.speed_percent) not in both]
    else:
        chosen = [d for d in chosen if d.key.direction != "both"]
    return sorted(chosen, key=lambda d: (d.key.pose, d.key.joint, d.key.direction, d.key.speed_percent))


def build_groups(sweeps: list[DeltaSweep], kin: Kinematics,
                 joints: Iterable[int] = GRAVITY_JOINTS) -> list[Group]:
    joints = tuple(joints)
    groups = []
    for d in sweeps:
        Y = np.array([kin.payload_regressor(q, joints) for q in d.q])  # (n, len(joints), 4)
        for c, j in enumerate(joints):
            Yj = Y[:, c, :]
            if np.max(np.abs(Yj)) < ZERO_ROW_TOL:
                continue
            groups.append(Group(f"{d.key.name}/j{j + 1}", d.key.name, Yj, np.asarray(d.dtau[:, j], float)))
    return groups


def _wls(Y: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted LS via a column-scaled QR-free lstsq; returns θ and (YᵀWY)⁻¹."""
    sw = np.sqrt(w)
    A = Y * sw[:, None]
    b = y * sw
    scale = np.sqrt(np.sum(A ** 2, axis=0))
    scale[scale == 0] = 1.0
    As = A / scale
    theta_s, *_ = np.linalg.lstsq(As, b, rcond=None)
    theta = theta_s / scale
    normal_s = As.T @ As
    inv = np.linalg.pinv(normal_s) / np.outer(scale, scale)
    return theta, inv


def fit(groups: list[Group]) -> dict:
    """Two-pass weighted fit. Returns θ, its covariance, per-group σ and residual RMS, condition number."""
    if not groups:
        raise DataError("general: no sweep carries any payload torque (no usable joint rows)")
    Y = np.vstack([g.Y for g in groups])
    y = np.concatenate([g.y for g in groups])
    n, p = Y.shape
    if n <= p:
        raise DataError(f"general: only {n} samples for {p} unknowns")
    idx = np.repeat(np.arange(len(groups)), [len(g.y) for g in groups])

    theta0, _ = _wls(Y, y, np.ones(n))
    r0 = y - Y @ theta0
    dof_factor = n / (n - p)
    sigma = np.array([np.sqrt(np.mean(r0[idx == i] ** 2) * dof_factor) for i in range(len(groups))])
    sigma = np.maximum(sigma, SIGMA_FLOOR_NM)
    w = 1.0 / sigma[idx] ** 2

    theta, inv = _wls(Y, y, w)
    r = y - Y @ theta
    s2 = float(r @ (w * r) / (n - p))
    cov = s2 * inv
    normal = (Y * w[:, None]).T @ Y
    d = 1.0 / np.sqrt(np.diag(normal))
    cond = float(np.linalg.cond(normal * np.outer(d, d)))
    rms = {g.label: float(np.sqrt(np.mean(r[idx == i] ** 2))) for i, g in enumerate(groups)}
    return {"theta": theta, "cov": cov, "sigma": dict(zip([g.label for g in groups], sigma.tolist())),
            "rms": rms, "cond": cond, "s2": s2, "n": n}


def cog_with_covariance(theta: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c = θ[1:]/θ[0] and its 3×3 covariance (delta method)."""
    m = theta[0]
    c = theta[1:] / m
    J = np.zeros((3, 4))
    J[:, 0] = -theta[1:] / m ** 2
    J[:, 1:] = np.eye(3) / m
    return c, J @ cov @ J.T


def solve(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, poses: Iterable[str] | None = None,
          use_combined: bool = True, name: str = NAME) -> Estimate:
    sweeps = select_sweeps(deltas, poses=poses, use_combined=use_combined)
    if not sweeps:
        which = "" if poses is None else f" in pose(s) {', '.join(sorted(poses))}"
        raise DataError(f"general: no sweep{which} to solve with")
    groups = build_groups(sweeps, kin)
    res = fit(groups)
    theta, cov = res["theta"], res["cov"]
    mass = float(theta[0])
    if not mass > 0:
        raise DataError(f"general: identified mass {mass:.4f} kg is not positive; is a payload mounted?")
    c, cov_c = cog_with_covariance(theta, cov)
    notes = []
    if res["cond"] > 1e6:
        notes.append(f"the sweeps hardly observe every parameter (condition number {res['cond']:.3g}); "
                     "add a second tool orientation")
    combined = [d.key.name for d in sweeps if d.key.direction == "both"]
    if combined:
        notes.append(f"bidirectional (friction-cancelling) sweeps used: {', '.join(combined)}")
    return Estimate(
        solver=name,
        mass_kg=mass,
        cog_m=(float(c[0]), float(c[1]), float(c[2])),
        residual_rms_nm=res["rms"],
        samples={d.key.name: len(d.q) for d in sweeps},
        mass_std_kg=float(np.sqrt(max(cov[0, 0], 0.0))),
        cog_std_m=tuple(float(np.sqrt(max(v, 0.0))) for v in np.diag(cov_c)),
        covariance=cov.tolist(),
        condition_number=res["cond"],
        notes=notes,
    )
