"""Fake-side models of the simulated Elite EC controller: joint temperatures and the reported flange pose.

Neither is Elite data: the temperatures are a first-order warm-up model; the pose is the
simulated arm's own DH chain, reported in Elite's units and rotation convention
(docs/sources.md, "Elite EC: the flange pose").
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from payload_agent.fakes.elite_ec_methods import is_number

# Joint temperatures (°C) served in the monitor frame's joint_temperature (6 doubles at offset 607). Fake-side
# model, not Elite data: the joints start at these values and warm towards the steady state with a 30-minute
# time constant of simulated time. No 8055 method is served for them: no public source names one.
DEFAULT_JOINT_TEMPS_C = (31.0, 32.5, 32.0, 34.5, 34.0, 33.5)
DEFAULT_STEADY_JOINT_TEMPS_C = (34.0, 36.5, 35.5, 38.0, 37.0, 36.0)
JOINT_TEMP_TAU_S = 1800.0


def _joint_temps(values: Sequence[float], what: str) -> np.ndarray:
    vals = list(values)
    if len(vals) != 6 or not all(is_number(v) and -40.0 <= float(v) <= 200.0 for v in vals):
        raise ValueError(f"{what} must be 6 numbers in [-40, 200] °C, got {values!r}")
    return np.asarray(vals, float)


class JointThermal:
    """Per-joint temperatures: a first-order lag towards ``steady`` in simulated time (tau ``JOINT_TEMP_TAU_S``)."""

    def __init__(self, start: Sequence[float], steady: Sequence[float], tau_s: float = JOINT_TEMP_TAU_S):
        self.value = np.asarray(start, float).copy()
        self.steady = np.asarray(steady, float).copy()
        self.tau_s = float(tau_s)
        self._t: float | None = None

    def set(self, values: Sequence[float], steady: Sequence[float] | None = None) -> None:
        self.value = _joint_temps(values, "joint temperatures")
        self.steady = self.value.copy() if steady is None else _joint_temps(steady, "steady joint temperatures")

    def advance(self, t: float) -> None:
        if self._t is not None and t > self._t:
            self.value = self.value + (self.steady - self.value) * (1.0 - math.exp(-(t - self._t) / self.tau_s))
        self._t = t


class FlangeFK:
    """The simulated arm's flange pose in Elite units: [x, y, z (mm), rx, ry, rz (rad)], R = Rz(rz)·Ry(ry)·Rx(rx).

    The same standard-DH chain as ``model.kinematics.Kinematics`` (Rz(q + offset) Tz(d) Tx(a) Rx(alpha)
    per row), in plain floats because the monitor computes it for every frame: thousands a second
    when the simulation runs faster than wall time, where small-array numpy costs several times more.
    """

    def __init__(self, rows):
        self.rows = [(r.a_m, r.d_m, math.cos(r.alpha_rad), math.sin(r.alpha_rad), r.offset_rad) for r in rows]

    def elite_pose(self, q) -> list[float]:
        r00, r01, r02, px = 1.0, 0.0, 0.0, 0.0
        r10, r11, r12, py = 0.0, 1.0, 0.0, 0.0
        r20, r21, r22, pz = 0.0, 0.0, 1.0, 0.0
        for qi, (a, d, ca, sa, off) in zip(q, self.rows):
            ct, st = math.cos(qi + off), math.sin(qi + off)
            # A = [[ct, -st ca, st sa, a ct], [st, ct ca, -ct sa, a st], [0, sa, ca, d]]
            act, ast, b01, b02, b11, b12 = a * ct, a * st, -st * ca, st * sa, ct * ca, -ct * sa
            px, py, pz = (px + r00 * act + r01 * ast + r02 * d, py + r10 * act + r11 * ast + r12 * d,
                          pz + r20 * act + r21 * ast + r22 * d)
            r00, r01, r02 = r00 * ct + r01 * st, r00 * b01 + r01 * b11 + r02 * sa, r00 * b02 + r01 * b12 + r02 * ca
            r10, r11, r12 = r10 * ct + r11 * st, r10 * b01 + r11 * b11 + r12 * sa, r10 * b02 + r11 * b12 + r12 * ca
            r20, r21, r22 = r20 * ct + r21 * st, r20 * b01 + r21 * b11 + r22 * sa, r20 * b02 + r21 * b12 + r22 * ca
        h = math.hypot(r00, r10)
        ry = math.atan2(-r20, h)
        if h > 1e-9:
            rx, rz = math.atan2(r21, r22), math.atan2(r10, r00)
        else:  # gimbal lock: put the whole rotation about z into rx
            rx, rz = math.atan2(-r12, r11), 0.0
        return [px * 1000.0, py * 1000.0, pz * 1000.0, rx, ry, rz]
