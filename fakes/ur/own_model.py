"""The simulated UR controller's own dynamics model: what it streams as ``target_moment`` and
``target_current``.

A real UR computes both from its model of the arm, not from the tool really on the flange:

* ``target_moment`` (N·m): the rigid-body torque of its arm model carrying the payload it was
  told (set_payload / set_target_payload, with the inertia where given), no friction;
* ``target_current`` (A): the current it commands, i.e. that torque plus its friction
  feed-forward, over its torque constant. An unknown tool changes neither (the real UR10e
  recordings in ``shared/realdata`` show the same target signals with and without the load).

Imperfections kept, as a real one has them: the friction feed-forward (Coulomb, smoothed at
standstill, plus viscous) is in the current only, so current and torque are not proportional;
and the commanded current carries a little noise from the controller's feedback terms. The
torque constants are the controller's ``gains`` (what a fit of one signal against the other
should find); the measured ``actual_current`` differs from them by the drives' own gain error.
"""

from __future__ import annotations

import threading
from typing import Sequence

import numpy as np

from payload_agent.fakes.physics import ArmPhysics, PayloadTruth

# Fake-side model values, not UR data (per joint): the friction feed-forward's Coulomb level (N·m),
# viscous coefficient (N·m·s/rad) and the speed below which the Coulomb term fades (rad/s); the
# noise of the commanded current (A).
FF_COULOMB_NM = (5.0, 5.0, 3.5, 1.3, 1.3, 1.3)
FF_VISCOUS_NM_S = (6.0, 6.0, 4.0, 1.2, 1.2, 1.2)
FF_FADE_RAD_S = 0.02
TARGET_CURRENT_NOISE_A = 0.004


def configured_payload(mass_kg: float, cog_m: Sequence[float], inertia_six: Sequence[float]) -> PayloadTruth | None:
    """The payload setting as the model's payload: mass, CoG and UR's [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] at the CoG."""
    if mass_kg <= 0:
        return None
    xx, yy, zz, xy, xz, yz = (float(v) for v in inertia_six)
    return PayloadTruth.from_tensor(mass_kg, tuple(cog_m), [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


class ControllerModel:
    """The arm model the controller computes its target torque and current with."""

    def __init__(self, spec, gains_nm_per_a: Sequence[float], seed: int | None):
        self.spec = spec
        self.gains = np.asarray(gains_nm_per_a, float)
        self._payload: PayloadTruth | None = None
        self._physics: ArmPhysics | None = None  # built on first use (the RTDE recipe may not ask)
        self._lock = threading.Lock()
        self._rng = np.random.default_rng(None if seed is None else seed + 104729)

    def set_payload(self, payload: PayloadTruth | None) -> None:
        with self._lock:
            self._payload = payload
            if self._physics is not None:
                self._physics.set_payload(payload)

    def moment(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """target_moment: rigid-body torque with the configured payload, no friction."""
        with self._lock:
            if self._physics is None:
                self._physics = ArmPhysics(self.spec, self._payload)
            return self._physics.rigid_torque(np.asarray(q), np.asarray(qd), np.asarray(qdd))

    def current(self, moment: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """target_current: (target moment + friction feed-forward) / torque constant, with the feedback noise."""
        qd = np.asarray(qd, float)
        ff = np.asarray(FF_COULOMB_NM) * np.tanh(qd / FF_FADE_RAD_S) + np.asarray(FF_VISCOUS_NM_S) * qd
        with self._lock:
            noise = self._rng.normal(0.0, TARGET_CURRENT_NOISE_A, len(qd))
        return (np.asarray(moment) + ff) / self.gains + noise
