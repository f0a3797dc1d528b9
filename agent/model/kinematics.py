"""Standard-DH forward kinematics: flange pose, joint axes and joint origins.

Everything here is in SI units and in the DH convention; ``Kinematics`` converts
controller joint angles to DH angles with the per-joint zero offsets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class DHRow:
    """Frame i from frame i-1: Rz(theta) Tz(d) Tx(a) Rx(alpha), theta = q + offset."""

    a_m: float
    d_m: float
    alpha_rad: float
    offset_rad: float = 0.0


def dh_transform(theta: float, row: DHRow) -> np.ndarray:
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(row.alpha_rad), np.sin(row.alpha_rad)
    return np.array(
        [
            [ct, -st * ca, st * sa, row.a_m * ct],
            [st, ct * ca, -ct * sa, row.a_m * st],
            [0.0, sa, ca, row.d_m],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def dh_transforms(theta: np.ndarray, a: float, d: float, alpha: float) -> np.ndarray:
    """Standard-DH transforms for an array of joint angles: (n, 4, 4), the batch of ``dh_transform``."""
    n = len(theta)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros((n, 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 0, 2], T[:, 0, 3] = ct, -st * ca, st * sa, a * ct
    T[:, 1, 0], T[:, 1, 1], T[:, 1, 2], T[:, 1, 3] = st, ct * ca, -ct * sa, a * st
    T[:, 2, 1], T[:, 2, 2], T[:, 2, 3] = sa, ca, d
    T[:, 3, 3] = 1.0
    return T


def fixed_part(row: DHRow) -> np.ndarray:
    """Tz(d) Tx(a) Rx(alpha): the part of a DH transform that does not turn with the joint."""
    return dh_transform(0.0, row)


@dataclass(frozen=True)
class ChainPose:
    """Poses of every DH frame for one joint configuration (base frame, SI)."""

    frames: tuple[np.ndarray, ...]  # frames[i] = T_0^i, i = 0..n (frames[0] = identity)

    @property
    def flange(self) -> np.ndarray:
        return self.frames[-1]

    def axis(self, j: int) -> np.ndarray:
        """Unit axis of joint j (0-based) = z of frame j."""
        return self.frames[j][:3, 2]

    def origin(self, j: int) -> np.ndarray:
        """A point on the axis of joint j (0-based) = origin of frame j."""
        return self.frames[j][:3, 3]


class Kinematics:
    """A serial arm of revolute joints described by standard DH rows."""

    def __init__(self, rows: Sequence[DHRow]):
        self.rows = tuple(rows)
        self.n = len(self.rows)

    def pose(self, q: Sequence[float]) -> ChainPose:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f"expected {self.n} joint angles, got shape {q.shape}")
        frames = [np.eye(4)]
        for qi, row in zip(q, self.rows):
            frames.append(frames[-1] @ dh_transform(qi + row.offset_rad, row))
        return ChainPose(tuple(frames))

    def flange(self, q: Sequence[float]) -> np.ndarray:
        return self.pose(q).flange

    def frames(self, q: np.ndarray) -> list[np.ndarray]:
        """Base-frame transforms of DH frames 0..n for every sample: a list of n+1 (N, 4, 4) arrays.

        The batch form of ``pose`` for joint angles q of shape (N, n) (one sample (n,) is taken as N = 1).
        Joint i (0-based) turns about z of frame i through its origin; frame n is the flange.
        """
        q = np.atleast_2d(np.asarray(q, float))
        if q.ndim != 2 or q.shape[1] != self.n:
            raise ValueError(f"expected {self.n} joint angles per sample, got shape {q.shape}")
        frames = [np.broadcast_to(np.eye(4), (len(q), 4, 4))]
        for i, row in enumerate(self.rows):
            frames.append(frames[-1] @ dh_transforms(q[:, i] + row.offset_rad, row.a_m, row.d_m, row.alpha_rad))
        return frames

    def payload_regressors(self, q: np.ndarray, joints: Sequence[int], g: float = GRAVITY_M_S2) -> np.ndarray:
        """``payload_regressor`` for every sample at once: q (N, n) -> Y (N, len(joints), 4).

        Y[k, r] · [m, m·cx, m·cy, m·cz] is the static torque joint ``joints[r]`` must add at sample k
        to hold a payload of mass m at c (flange frame, SI) against gravity; the support force is
        g⃗ = (0, 0, g). With z the joint axis, o a point on it and p, R the flange pose:
            Y[0] = z · ((p − o) × g⃗),   Y[1:4] = Rᵀ (g⃗ × z)
        written out component-wise (g⃗ has only a z component), without per-sample np.cross.
        """
        joints = tuple(joints)
        frames = self.frames(q)
        flange = frames[-1]
        p = flange[:, :3, 3]
        R = flange[:, :3, :3]
        Y = np.empty((len(p), len(joints), 4))
        for r, j in enumerate(joints):
            z = frames[j][:, :3, 2]
            a = p - frames[j][:, :3, 3]
            # (a × g⃗) = g·(a_y, −a_x, 0);  g⃗ × z = g·(−z_y, z_x, 0)
            Y[:, r, 0] = g * (z[:, 0] * a[:, 1] - z[:, 1] * a[:, 0])
            gz = np.stack((-g * z[:, 1], g * z[:, 0], np.zeros(len(z))), axis=1)
            Y[:, r, 1:] = np.einsum("nij,ni->nj", R, gz)  # Rᵀ (g⃗ × z)
        return Y

    def payload_regressor(self, q: Sequence[float], joints: Sequence[int], g: float = GRAVITY_M_S2) -> np.ndarray:
        """Rows of Y(q) with Δτ_j = Y_j · [m, m·cx, m·cy, m·cz] (c in the flange frame, SI).

        Δτ_j is the static torque the joint-j motor must add to hold a payload of
        mass m at c against gravity (g⃗ = (0, 0, g) is the supporting force direction).
        One sample of ``payload_regressors`` (one formula for both).
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f"expected {self.n} joint angles, got shape {q.shape}")
        return self.payload_regressors(q[None, :], joints, g)[0]
