"""The simulated robot behind every fake controller: motion, clock, sensors, safety state.

A clock thread advances simulated time in fixed ticks, paced at ``time_scale``
times wall time (slower if the machine cannot keep up: no tick is ever skipped,
so every front end sees a gap-free sample stream in simulated time).
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from payload_agent.fakes.physics import ArmPhysics, ArmSpec, FrictionParams, PayloadTruth
from payload_agent.model.profile import JointPath


class SimRefused(Exception):
    """The simulated controller refuses a command (the reason is a short sentence)."""


@dataclass(frozen=True)
class SimState:
    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    torque_nm: np.ndarray  # rigid-body dynamics + friction + noise: what the drives report
    moving: bool
    estop: bool
    protective_stop: bool
    servo_on: bool
    move_id: int


StateCallback = Callable[[SimState], None]


class SimRobot:
    def __init__(self, spec: ArmSpec, *, q0_rad: Sequence[float], tick_s: float = 0.008,
                 time_scale: float = 1.0, friction: FrictionParams | None = None,
                 noise_nm: float | Sequence[float] = 0.0, seed: int | None = None,
                 payload: PayloadTruth | None = None, stop_decel_rad_s2: float = 3.0):
        self.spec = spec
        self.physics = ArmPhysics(spec, payload)
        self.tick_s = float(tick_s)
        self.time_scale = float(time_scale)
        self.friction = friction or FrictionParams()
        self.noise_nm = np.broadcast_to(np.asarray(noise_nm, float), (6,)).copy()
        self.rng = np.random.default_rng(seed)
        self.stop_decel_rad_s2 = stop_decel_rad_s2
        self._max_speed = np.asarray(spec.max_speed_rad_s, float)
        self._max_accel = np.asarray(spec.max_accel_rad_s2, float)
        self._lock = threading.RLock()
        self._t = 0.0
        self._q = np.asarray(q0_rad, float).copy()
        self._path: JointPath | None = None
        self._move_id = 0
        self._estop = False
        self._protective = False
        self._servo = True
        self._subscribers: dict[int, StateCallback] = {}
        self._tokens = itertools.count(1)
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._state = self._compute_state()

    # -- clock ------------------------------------------------------------------------------
    def start(self) -> "SimRobot":
        if self._thread is None:
            self._running.set()
            self._thread = threading.Thread(target=self._run, name=f"sim-{self.spec.name}", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        self._running.clear()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> "SimRobot":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _run(self) -> None:
        period = self.tick_s / self.time_scale
        next_wall = time.monotonic()
        while self._running.is_set():
            state = self.step()
            for cb in list(self._subscribers.values()):
                try:
                    cb(state)
                except Exception:  # a broken front end must not kill the clock
                    pass
            next_wall += period
            delay = next_wall - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.05:  # behind: slow simulated time down rather than burst
                next_wall = time.monotonic()

    def step(self) -> SimState:
        """Advance simulated time by one tick (called by the clock thread, or by tests directly)."""
        with self._lock:
            self._t += self.tick_s
            self._state = self._compute_state()
            if self._path is not None and self._t >= self._path.t_end:
                self._q = self._path.at(self._path.t_end)[0]
                self._path = None
                self._state = self._compute_state()
            return self._state

    def _compute_state(self) -> SimState:
        t = self._t
        if self._path is not None:
            q, qd, qdd = self._path.at(t)
        else:
            q, qd, qdd = self._q, np.zeros(6), np.zeros(6)
        rigid = self.physics.rigid_torque(q, qd, qdd)
        tau = rigid + self.friction.torque(qd, rigid) + self.rng.normal(0.0, 1.0, 6) * self.noise_nm
        return SimState(t, q.copy(), qd.copy(), qdd.copy(), tau, self._path is not None, self._estop,
                        self._protective, self._servo, self._move_id)

    def now(self) -> float:
        with self._lock:
            return self._t

    def snapshot(self) -> SimState:
        with self._lock:
            return self._state

    def subscribe(self, callback: StateCallback) -> int:
        token = next(self._tokens)
        self._subscribers[token] = callback
        return token

    def unsubscribe(self, token: int) -> None:
        self._subscribers.pop(token, None)

    # -- commands ---------------------------------------------------------------------------
    def move_joints(self, target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float) -> float:
        target = np.asarray(target_rad, float)
        if target.shape != (6,):
            raise SimRefused("target must have 6 joint values")
        with self._lock:
            self._refuse_unless_ready()
            self._path = JointPath(self._state.q, target, self._t, speed_rad_s, accel_rad_s2,
                                   self._max_speed, self._max_accel)
            self._move_id += 1
            return self._path.t_end - self._t

    def _refuse_unless_ready(self) -> None:
        """What a real controller checks before accepting a motion command (caller holds the lock)."""
        if self._estop:
            raise SimRefused("emergency stop is active")
        if self._protective:
            raise SimRefused("protective stop is active")
        if not self._servo:
            raise SimRefused("servos are off")
        if self._path is not None:
            raise SimRefused("robot is moving")

    def follow_path(self, make_path: Callable[[float, np.ndarray], object]) -> float:
        """Start a continuous joint trajectory instead of a PTP move (e.g. an excitation trajectory).

        ``make_path(t0, q0)`` gets the current simulated time and angles and returns an object
        with ``at(t) -> (q, q̇, q̈)``, ``t_end`` and ``stop_at(t, decel)``, like ``JointPath``;
        ``step()`` then follows it tick by tick exactly as it follows a PTP profile. Same
        refusals as ``move_joints``. Returns the trajectory's duration (s).
        """
        with self._lock:
            self._refuse_unless_ready()
            path = make_path(self._t, self._state.q.copy())
            if np.max(np.abs(np.asarray(path.at(self._t)[0]) - self._state.q)) > 1e-6:
                raise SimRefused("trajectory does not start at the current joint angles")
            self._path = path
            self._move_id += 1
            return path.t_end - self._t

    def stop(self, decel_rad_s2: float | None = None) -> None:
        with self._lock:
            if self._path is not None:
                self._path.stop_at(self._t, decel_rad_s2 or self.stop_decel_rad_s2)

    def set_payload(self, payload: PayloadTruth | None) -> None:
        with self._lock:
            self.physics.set_payload(payload)

    @property
    def payload(self) -> PayloadTruth | None:
        return self.physics.payload

    def set_friction_scale(self, scale: float) -> None:
        with self._lock:
            self.friction.scale = float(scale)

    def set_servo(self, on: bool) -> None:
        with self._lock:
            if not on:
                self.stop(self.stop_decel_rad_s2 * 3)
            self._servo = bool(on)

    def trigger_protective_stop(self) -> None:
        with self._lock:
            self._protective = True
            self.stop(self.stop_decel_rad_s2 * 3)

    def trigger_estop(self) -> None:
        with self._lock:
            self._estop = True
            self.stop(self.stop_decel_rad_s2 * 5)

    def reset_safety(self) -> None:
        with self._lock:
            self._estop = False
            self._protective = False
