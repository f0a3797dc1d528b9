"""The geometry the procedure speaks in, derived from forward kinematics only.

Link elevations (angle of links 2 and 3 above horizontal, in the plane of motion of
the parallel joints 2 and 3) and the "arm frame" of link 3 (arm, axis, up). No
robot's signs are hard-coded: slopes and offsets are measured on the DH model.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

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

        def residual(w):
            return (self.kin.flange(self._q(q2, q3, w))[:3, :3] - R_des).ravel()

        prefer = np.zeros(3) if prefer is None else np.asarray(prefer, float)
        candidates = []
        for seed in np.array(np.meshgrid(*[np.linspace(-math.pi, math.pi, 4, endpoint=False)] * 3)).T.reshape(-1, 3):
            sol = least_squares(residual, seed, xtol=1e-14, ftol=1e-14, gtol=1e-14)
            if np.max(np.abs(sol.fun)) > 1e-9:
                continue
            w = np.array([wrap(v) for v in sol.x])
            # use the equivalent angle (±2π) nearest the preference, if the limits allow it
            for i in range(3):
                for alt in (w[i] - 2 * math.pi, w[i] + 2 * math.pi):
                    if abs(alt - prefer[i]) < abs(w[i] - prefer[i]):
                        w[i] = alt
            if all(lo <= v <= hi for v, (lo, hi) in zip(w, limits)):
                candidates.append(w)
        if not candidates:
            raise PlanError("no wrist angles within the joint limits give the requested tool orientation")
        def height(w):
            return round(float(self.kin.flange(self._q(q2, q3, w))[2, 3]), 6)

        best = min(candidates, key=lambda w: (-height(w), float(np.sum((w - prefer) ** 2))))
        # to 1e-4 degree (2e-6 rad, below any controller's resolution), inside the limits: the solver's last
        # digits are noise (179.999998 for 180), not geometry
        lo, hi = np.array(limits, float).T
        return np.clip(np.radians(np.round(np.degrees(best), 4)), lo, hi)
