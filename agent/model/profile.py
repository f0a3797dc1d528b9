"""Synchronised trapezoidal PTP profiles, as industrial controllers run joint moves.

All joints move along the straight joint-space segment from start to target and
arrive together; the leading joint (largest travel) follows a trapezoidal speed
profile within the speed and acceleration caps.

This is the one place that math lives. Drivers use it to turn a leading-joint speed
into the percentage a controller's PTP command takes (``percent_for_lead``), into one
trapezoid per joint in whole position units (``synchronised_profiles``, ``whole_unit_rates``) and to
predict durations (``trapezoid_duration``); simulated controllers use it the other way
(``lead_from_percent``) and to run the motion (``JointPath``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class LeadCaps:
    """The leading joint's speed and acceleration when every joint runs at its own 100 %."""

    speed_rad_s: float
    accel_rad_s2: float


def lead_joint_caps(q_from: Sequence[float], q_to: Sequence[float], max_speed_rad_s: Sequence[float],
                    max_accel_rad_s2: Sequence[float]) -> LeadCaps:
    """How fast the leading joint of a synchronised move from ``q_from`` to ``q_to`` may go.

    Joint j travels |Δq_j| / max|Δq| of the leading joint's distance, so it turns at that
    fraction of the leading joint's speed; the leading joint's cap is the smallest
    ``max_speed_j / fraction_j`` over the joints that move (same for acceleration). A move
    of zero length has the smallest joint maximum as its cap.
    """
    vmax = np.broadcast_to(np.asarray(max_speed_rad_s, float), np.shape(q_from))
    amax = np.broadcast_to(np.asarray(max_accel_rad_s2, float), np.shape(q_from))
    d = np.abs(np.asarray(q_to, float) - np.asarray(q_from, float))
    lead = float(d.max()) if d.size else 0.0
    if lead <= 0.0:
        return LeadCaps(float(vmax.min()), float(amax.min()))
    scale = d / lead
    mask = scale > 1e-12
    return LeadCaps(float(np.min(vmax[mask] / scale[mask])), float(np.min(amax[mask] / scale[mask])))


def lead_from_percent(caps: LeadCaps, speed_percent: float, accel_percent: float) -> tuple[float, float]:
    """The leading joint's speed (rad/s) and acceleration (rad/s²) for a PTP command's percentages."""
    return caps.speed_rad_s * speed_percent / 100.0, caps.accel_rad_s2 * accel_percent / 100.0


def percent_for_lead(caps: LeadCaps, speed_rad_s: float, accel_rad_s2: float) -> tuple[float, float]:
    """The inverse of ``lead_from_percent``: the percentages (unclamped) that give this leading-joint motion."""
    return speed_rad_s / caps.speed_rad_s * 100.0, accel_rad_s2 / caps.accel_rad_s2 * 100.0


def trapezoid_duration(length_rad: float, speed_rad_s: float, accel_rad_s2: float) -> float:
    """Duration of a trapezoidal (or, if too short to cruise, triangular) profile over ``length_rad``."""
    L = abs(float(length_rad))
    if speed_rad_s <= 0 or accel_rad_s2 <= 0:
        raise ValueError("speed and acceleration must be positive")
    if L == 0.0:
        return 0.0
    if L < speed_rad_s * speed_rad_s / accel_rad_s2:
        return 2.0 * math.sqrt(L / accel_rad_s2)
    return L / speed_rad_s + speed_rad_s / accel_rad_s2


def synchronised_joint_rates(q_from: Sequence[float], q_to: Sequence[float], lead_speed_rad_s: float,
                             lead_accel_rad_s2: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint speed and acceleration (≥ 0) that make independent trapezoids arrive together.

    For controllers that run one profile per joint (CANopen drives in profile position mode):
    joint j gets the leading joint's speed and acceleration times its travel fraction
    |Δq_j| / max|Δq|, so every joint's trapezoid has the leading joint's timing and the arm
    follows the straight joint-space segment, as ``JointPath`` does. Joints that do not move get 0.
    """
    d = np.abs(np.asarray(q_to, float) - np.asarray(q_from, float))
    lead = float(d.max()) if d.size else 0.0
    if lead <= 0.0:
        return np.zeros_like(d), np.zeros_like(d)
    scale = d / lead
    return scale * float(lead_speed_rad_s), scale * float(lead_accel_rad_s2)


def capped_lead(q_from: Sequence[float], q_to: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                max_speed_rad_s: Sequence[float], max_accel_rad_s2: Sequence[float]) -> tuple[float, float]:
    """The requested leading-joint speed and acceleration, limited so no joint of the synchronised move from
    ``q_from`` to ``q_to`` exceeds its own maxima (``lead_joint_caps``)."""
    caps = lead_joint_caps(q_from, q_to, max_speed_rad_s, max_accel_rad_s2)
    return min(speed_rad_s, caps.speed_rad_s), min(accel_rad_s2, caps.accel_rad_s2)


@dataclass(frozen=True)
class JointProfiles:
    """One trapezoid per joint, all arriving together after ``duration_s``."""

    speeds_rad_s: np.ndarray
    accels_rad_s2: np.ndarray
    duration_s: float


def synchronised_profiles(q_from: Sequence[float], q_to: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                          max_speed_rad_s: Sequence[float], max_accel_rad_s2: Sequence[float]) -> JointProfiles:
    """The per-joint profiles of a synchronised move whose leading joint is asked for ``speed_rad_s`` and
    ``accel_rad_s2`` (``capped_lead``, then ``synchronised_joint_rates``), and how long it lasts."""
    v, a = capped_lead(q_from, q_to, speed_rad_s, accel_rad_s2, max_speed_rad_s, max_accel_rad_s2)
    speeds, accels = synchronised_joint_rates(q_from, q_to, v, a)
    length = float(np.max(np.abs(np.asarray(q_to, float) - np.asarray(q_from, float))))
    return JointProfiles(speeds, accels, trapezoid_duration(length, v, a))


def whole_unit_rates(speed: float, accel: float, travel: float, duration_s: float) -> tuple[int, int]:
    """One joint's speed and acceleration of a synchronised move in whole position units (counts/s,
    counts/s², as a drive's profile objects take them), for its ``travel`` in the same units.

    The synchronised values rounded up, so the joint never arrives late; a travel so short that even
    1 unit/s or 1 unit/s² would make it late gets the triangle over its travel that lasts the leading
    joint's ``duration_s``.
    """
    d, t = abs(float(travel)), max(float(duration_s), 1e-3)
    v, a = max(1, math.ceil(speed)), max(1, math.ceil(accel))
    if trapezoid_duration(d, v, a) > 1.01 * t:  # (rounding of the travel itself makes ~1e-7 s of difference)
        v, a = max(v, math.ceil(2 * d / t)), max(a, math.ceil(4 * d / (t * t)))
    return v, a


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
        v, a = capped_lead(self.start, self.target, speed, accel, max_speed, max_accel)
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
