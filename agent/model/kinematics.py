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

    def payload_regressor(self, q: Sequence[float], joints: Sequence[int], g: float = GRAVITY_M_S2) -> np.ndarray:
        """Rows of Y(q) with Δτ_j = Y_j · [m, m·cx, m·cy, m·cz] (c in the flange frame, SI).

        Δτ_j is the static torque the joint-j motor must add to hold a payload of
        mass m at c against gravity (g⃗ = (0, 0, g) is the supporting force direction).
        """
        pose = self.pose(q)
        p = pose.flange[:3, 3]
        R = pose.flange[:3, :3]
        gvec = np.array([0.0, 0.0, g])
        rows = []
        for j in joints:
            z = pose.axis(j)
            o = pose.origin(j)
            rows.append(np.concatenate(([z @ np.cross(p - o, gvec)], R.T @ np.cross(gvec, z))))
        return np.array(rows)
