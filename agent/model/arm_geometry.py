"""The geometry the procedure speaks in, derived from forward kinematics only.

Link elevations (angle of links 2 and 3 above horizontal, in the plane of motion of
the parallel joints 2 and 3) and the "arm frame" of link 3 (arm, axis, up). No
robot's signs are hard-coded: slopes and offsets are measured on the DH model.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from payload_agent.errors import PlanError
from payload_agent.model.kinematics import Kinematics

Z_UP = np.array([0.0, 0.0, 1.0])


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class ArmGeometry:
    def __init__(self, kin: Kinematics, base_rad: float):
        self.kin = kin
        self.base = base_rad
        pose = kin.pose(self._q(0.0, 0.0, (0.0, 0.0, 0.0)))
        z2 = pose.axis(1)
        if abs(z2 @ Z_UP) > 1e-6 or abs(abs(pose.axis(2) @ z2) - 1) > 1e-6:
            raise PlanError("this procedure needs joints 2 and 3 parallel and horizontal; the DH model says otherwise")
        # horizontal direction in the plane of motion: elevation 0 points the link this way
        self.h = np.cross(Z_UP, z2)
        self.h /= np.linalg.norm(self.h)
        # of the two horizontal directions, take the one the arm points to at its zero angles,
        # so that sweeps start near the controller's zero (no joint wraps through ±180°)
        for v in (pose.origin(2) - pose.origin(1), pose.origin(3) - pose.origin(2)):
            if abs(v @ self.h) > 1e-6:
                self.h = self.h if v @ self.h > 0 else -self.h
                break
        # "up" is fixed in link 3: the side of the arm that faces up when the arm is horizontal
        self._up_sign = 1.0 if np.cross(z2, self.h) @ Z_UP > 0 else -1.0
        # elevations are affine in (q2, q3): measure offsets and slopes on the model
        e2_0, e3_0 = self.elevations(0.0, 0.0)
        e2_a, e3_a = self.elevations(0.1, 0.0)
        e2_b, e3_b = self.elevations(0.0, 0.1)
        self._A = np.array([[wrap(e2_a - e2_0), wrap(e2_b - e2_0)], [wrap(e3_a - e3_0), wrap(e3_b - e3_0)]]) / 0.1
        self._c = np.array([e2_0, e3_0])

    def _q(self, q2: float, q3: float, wrist) -> np.ndarray:
        return np.array([self.base, q2, q3, *wrist], dtype=float)

    def _elev(self, v: np.ndarray, axis: np.ndarray) -> float:
        v = v - (v @ axis) * axis
        return math.atan2(v @ Z_UP, v @ self.h)

    def elevations(self, q2: float, q3: float) -> tuple[float, float]:
        pose = self.kin.pose(self._q(q2, q3, (0.0, 0.0, 0.0)))
        axis = pose.axis(1)
        link2 = pose.origin(2) - pose.origin(1)
        link3 = pose.origin(3) - pose.origin(2)
        return self._elev(link2, axis), self._elev(link3, axis)

    def joints_for(self, elev2: float, elev3: float) -> tuple[float, float]:
        """(q2, q3) that put link 2 at ``elev2`` and link 3 at ``elev3`` (rad above horizontal)."""
        rhs = np.array([wrap(elev2 - self._c[0]), wrap(elev3 - self._c[1])])
        q2, q3 = np.linalg.solve(self._A, rhs)
        q2, q3 = wrap(q2), wrap(q3)
        e2, e3 = self.elevations(q2, q3)
        if abs(wrap(e2 - elev2)) > 1e-9 or abs(wrap(e3 - elev3)) > 1e-9:
            raise PlanError("could not place links 2 and 3 at the requested elevations (DH model not planar?)")
        return q2, q3

    def arm_frame(self, q: np.ndarray) -> dict[str, np.ndarray]:
        pose = self.kin.pose(q)
        axis = pose.axis(1)
        arm = pose.origin(3) - pose.origin(2)
        arm = arm - (arm @ axis) * axis
        arm /= np.linalg.norm(arm)
        up = self._up_sign * np.cross(axis, arm)
        frame = {"arm": arm, "axis": axis, "up": up}
        frame.update({f"-{k}": -v for k, v in list(frame.items())})
        return frame

    def tool_rotation(self, q: np.ndarray, tool_x: str, tool_z: str) -> np.ndarray:
        f = self.arm_frame(q)
        x, z = f[tool_x], f[tool_z]
        return np.column_stack([x, np.cross(z, x), z])

    def wrist_for(self, q2: float, q3: float, R_des: np.ndarray, limits: list[tuple[float, float]],
                  prefer: np.ndarray | None = None) -> np.ndarray:
        """Joints 4-6 that give the flange the rotation R_des, within ``limits``.

        Of the wrist solutions, the one that holds the flange highest (clear of the table)
        wins; ties go to the one nearest ``prefer``.
        """
        prefer = np.zeros(3) if prefer is None else np.asarray(prefer, float)
        candidates = []
        for w in self._wrist_solutions(q2, q3, R_des, prefer[0]):
            # every equivalent angle (±2π) inside the limits; the ranking below takes the nearest the preference
            turns = [[v + 2 * math.pi * k for k in (-1, 0, 1) if lo <= v + 2 * math.pi * k <= hi]
                     for v, (lo, hi) in zip(w, limits)]
            candidates += [np.array(c) for c in itertools.product(*turns)]
        if not candidates:
            raise PlanError("no wrist angles within the joint limits give the requested tool orientation")

        def height(w):
            return round(float(self.kin.flange(self._q(q2, q3, w))[2, 3]), 6)

        # the last key makes a tie (a joint at +180° or -180°, equally far from the preference) a fixed choice, the
        # larger angle: the plan must not depend on the solver's last digits (a run's start shifts whole turns)
        best = min(candidates, key=lambda w: (-height(w), round(float(np.sum((w - prefer) ** 2)), 9),
                                              tuple(-np.round(w, 6))))
        # to 1e-4 degree (2e-6 rad, below any controller's resolution), inside the limits: the last digits of
        # the trigonometry are noise (179.999998 for 180), not geometry
        lo, hi = np.array(limits, float).T
        return np.clip(np.radians(np.round(np.degrees(best), 4)), lo, hi)

    def _wrist_solutions(self, q2: float, q3: float, R_des: np.ndarray, q4_free: float) -> list[np.ndarray]:
        """Every (q4, q5, q6), wrapped to ±π, that gives the flange the rotation R_des: in closed form.

        The wrist's rotation is Rz(θ4) Rx(α4) Rz(θ5) Rx(α5) Rz(θ6) Rx(α6) (standard DH, θ = q + offset), a
        generalised Euler decomposition: θ5 from one element (two solutions), θ4 and θ6 from the column and
        row it leaves. Where θ5 lines joints 4 and 6 up (only their sum counts) q4 takes ``q4_free``.
        """
        r4, r5, r6 = self.kin.rows[3:6]
        R3 = self.kin.pose(self._q(q2, q3, (0.0, 0.0, 0.0))).frames[3][:3, :3]
        M = R3.T @ R_des @ _rx(r6.alpha_rad).T  # = Rz(θ4) Rx(α4) Rz(θ5) Rx(α5) Rz(θ6)
        s45 = math.sin(r4.alpha_rad) * math.sin(r5.alpha_rad)
        if abs(s45) < 1e-9:
            raise PlanError("joints 4-6 of the DH model do not form a wrist (parallel axes): no wrist solution")
        c5 = (math.cos(r4.alpha_rad) * math.cos(r5.alpha_rad) - M[2, 2]) / s45
        if abs(c5) > 1 + 1e-9:
            return []
        out = []
        for t5 in {math.acos(max(-1.0, min(1.0, c5))), -math.acos(max(-1.0, min(1.0, c5)))}:
            inner = _rx(r4.alpha_rad) @ _rz(t5) @ _rx(r5.alpha_rad)  # = Rz(θ4)ᵀ M Rz(θ6)ᵀ
            col = inner[:, 2]  # M's last column is Rz(θ4) of it
            if math.hypot(col[0], col[1]) > 1e-9:
                t4 = math.atan2(M[1, 2], M[0, 2]) - math.atan2(col[1], col[0])
            else:  # joints 4 and 6 in line: joint 4 (the heavier) stays where preferred, joint 6 takes the rest
                t4 = q4_free + r4.offset_rad
            N = inner.T @ _rz(t4).T @ M  # = Rz(θ6)
            t6 = math.atan2(N[1, 0], N[0, 0])
            w = np.array([wrap(t4 - r4.offset_rad), wrap(t5 - r5.offset_rad), wrap(t6 - r6.offset_rad)])
            if np.max(np.abs(self.kin.flange(self._q(q2, q3, w))[:3, :3] - R_des)) < 1e-9:
                out.append(w)
        return out


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
