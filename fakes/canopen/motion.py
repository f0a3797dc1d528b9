"""Independent per-joint trapezoids, as six profile position drives run them, for ``SimRobot.follow_path``.

Each drive plans its own profile from its own target, profile velocity, acceleration and
deceleration (in its own position units, converted to joint radians by the caller); nothing
makes the joints arrive together except a master that scaled those values so. A quick stop
or a fault stops one joint at its own deceleration while the others carry on.
"""

from __future__ import annotations

import math

import numpy as np


class AxisProfile:
    """One joint's trapezoid (or triangle) from q0 to q1: phases (t_start, duration, q, v, a)."""

    def __init__(self, q0: float, q1: float, speed: float, accel: float, decel: float, t0: float):
        self.target = q1
        length, sign = abs(q1 - q0), (1.0 if q1 >= q0 else -1.0)
        self.phases: list[tuple[float, float, float, float, float]] = []
        if length == 0.0:
            self.phases = [(t0, 0.0, q0, 0.0, 0.0)]
        else:
            v = speed
            if v * v / (2 * accel) + v * v / (2 * decel) > length:  # no cruise: triangular
                v = math.sqrt(2 * length * accel * decel / (accel + decel))
            t_a, t_d = v / accel, v / decel
            t_c = (length - v * v / (2 * accel) - v * v / (2 * decel)) / v
            q_a = q0 + sign * v * t_a / 2
            q_c = q_a + sign * v * t_c
            self.phases = [(t0, t_a, q0, 0.0, sign * accel), (t0 + t_a, t_c, q_a, sign * v, 0.0),
                           (t0 + t_a + t_c, t_d, q_c, sign * v, -sign * decel)]
        self.t_end = self.phases[-1][0] + self.phases[-1][1]
        self.stopped_early = False

    def at(self, t: float) -> tuple[float, float, float]:
        for t0, dur, q, v, a in self.phases:
            if t < t0 + dur:
                dt = max(t - t0, 0.0)
                return q + v * dt + 0.5 * a * dt * dt, v + a * dt, a
        t0, dur, q, v, a = self.phases[-1]
        return q + v * dur + 0.5 * a * dur * dur, 0.0, 0.0

    def stop_at(self, t: float, decel: float) -> None:
        if t >= self.t_end:
            return
        q, v, _ = self.at(t)
        dur = abs(v) / decel if v else 0.0
        self.phases = [(t, dur, q, v, -math.copysign(decel, v) if v else 0.0)]
        self.t_end = t + dur
        self.stopped_early = True


class MultiAxisPath:
    """Six joints, each on its own profile or holding still; the ``JointPath`` interface SimRobot follows."""

    def __init__(self, q_now: np.ndarray, profiles: dict[int, AxisProfile]):
        self.hold = np.asarray(q_now, float).copy()
        self.profiles = profiles
        self.pending_stops: dict[int, float] = {}  # joint -> decel, applied by stop_at under SimRobot's lock
        self.t_end = max(p.t_end for p in profiles.values())

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q, qd, qdd = self.hold.copy(), np.zeros(6), np.zeros(6)
        for j, p in self.profiles.items():
            q[j], qd[j], qdd[j] = p.at(t)
        return q, qd, qdd

    def stop_at(self, t: float, decel: float) -> None:
        """Stop the joints in ``pending_stops`` at their own deceleration; with none pending, every joint."""
        stops, self.pending_stops = self.pending_stops, {}
        for j, p in self.profiles.items():
            if not stops or j in stops:
                p.stop_at(t, stops.get(j, decel))
        self.t_end = max(max(p.t_end for p in self.profiles.values()), t)
