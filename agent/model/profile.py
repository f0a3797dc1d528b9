"""Synchronized trapezoidal PTP profiles, as industrial controllers run joint moves.

All joints move along the straight joint-space segment from start to target and
arrive together; the leading joint (largest travel) follows a trapezoidal speed
profile within the speed and acceleration caps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PathPhase:
    """s(t) = s0 + v0·t + a·t²/2 for t in [t0, t0 + duration)."""

    t0: float
    duration: float
    s0: float
    v0: float
    a: float

    def at(self, t: float) -> tuple[float, float, float]:
        dt = min(max(t - self.t0, 0.0), self.duration)
        return self.s0 + self.v0 * dt + 0.5 * self.a * dt * dt, self.v0 + self.a * dt, self.a


class JointPath:
    """Straight joint-space path from ``start`` to ``target`` with a piecewise-quadratic s(t)."""

    def __init__(self, start: np.ndarray, target: np.ndarray, t_start: float, speed: float, accel: float,
                 max_speed: np.ndarray, max_accel: np.ndarray):
        self.start = np.asarray(start, float)
        self.target = np.asarray(target, float)
        delta = self.target - self.start
        self.length = float(np.max(np.abs(delta)))
        self.direction = delta / self.length if self.length > 0 else np.zeros_like(delta)
        # the leading joint's caps, limited so no joint exceeds its own
        scale = np.abs(self.direction)
        with np.errstate(divide="ignore"):
            v_cap = np.min(np.where(scale > 0, max_speed / np.where(scale > 0, scale, 1), np.inf))
            a_cap = np.min(np.where(scale > 0, max_accel / np.where(scale > 0, scale, 1), np.inf))
        v = min(speed, v_cap)
        a = min(accel, a_cap)
        if v <= 0 or a <= 0:
            raise ValueError("speed and acceleration must be positive")
        L = self.length
        if L == 0:
            self.phases = [PathPhase(t_start, 0.0, 0.0, 0.0, 0.0)]
        elif L < v * v / a:  # triangular
            t_acc = np.sqrt(L / a)
            v_peak = a * t_acc
            self.phases = [PathPhase(t_start, t_acc, 0.0, 0.0, a),
                           PathPhase(t_start + t_acc, t_acc, L / 2, v_peak, -a)]
        else:
            t_acc = v / a
            d_acc = 0.5 * a * t_acc * t_acc
            t_flat = (L - 2 * d_acc) / v
            self.phases = [PathPhase(t_start, t_acc, 0.0, 0.0, a),
                           PathPhase(t_start + t_acc, t_flat, d_acc, v, 0.0),
                           PathPhase(t_start + t_acc + t_flat, t_acc, L - d_acc, v, -a)]
        self.t_end = self.phases[-1].t0 + self.phases[-1].duration

    def _phase(self, t: float) -> PathPhase:
        for ph in self.phases:
            if t < ph.t0 + ph.duration:
                return ph
        return self.phases[-1]

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint position, velocity and acceleration at time t."""
        if t >= self.t_end:
            s, v, a = self.phases[-1].at(self.t_end)
            return self.start + self.direction * s, np.zeros_like(self.start), np.zeros_like(self.start)
        s, v, a = self._phase(t).at(t)
        return self.start + self.direction * s, self.direction * v, self.direction * a

    def stop_at(self, t: float, decel: float) -> None:
        """Replace the rest of the path by a ramp down to standstill starting at time t."""
        if t >= self.t_end:
            return
        s, v, _ = self._phase(t).at(t)
        if v <= 0:
            self.phases = [PathPhase(t, 0.0, s, 0.0, 0.0)]
            self.t_end = t
            return
        dur = v / decel
        self.phases = [PathPhase(t, dur, s, v, -decel)]
        self.t_end = t + dur
