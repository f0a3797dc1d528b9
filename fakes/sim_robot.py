"""The simulated robot behind every fake controller: motion, clock, sensors, safety state.

A clock thread advances simulated time in fixed ticks, paced at ``time_scale``
times wall time (slower if the machine cannot keep up: no tick is ever skipped,
so every front end sees a gap-free sample stream in simulated time).
"""

from __future__ import annotations

import dataclasses
import itertools
import threading
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from payload_agent.fakes.effects import PhysicsEffects, ripple_phases
from payload_agent.fakes.physics import ArmPhysics, ArmSpec, FrictionParams, PayloadTruth
from payload_agent.model.profile import JointPath


class SimRefused(Exception):
    """The simulated controller refuses a command (the reason is a short sentence)."""


@dataclass(frozen=True)
class SimState:
    """What the controller reports at one tick (``t``, ``q``, ``torque_nm``), and the truth behind it.

    ``t`` and ``q`` carry the timestamp jitter and angle noise of ``PhysicsEffects``; front ends serve
    them as they are. ``t_true`` / ``q_true`` are the exact simulated time and the controller's
    noise-free (motor-side) angles; ``q_link`` the links' physical angles (zero offsets and gear
    elasticity applied); ``temperature_c`` the joint temperatures the friction model used.
    """

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    torque_nm: np.ndarray  # rigid-body dynamics + friction + effects + noise: what the drives report
    moving: bool
    estop: bool
    protective_stop: bool
    servo_on: bool
    move_id: int
    t_true: float | None = None
    q_true: np.ndarray | None = None
    q_link: np.ndarray | None = None
    temperature_c: np.ndarray | None = None


StateCallback = Callable[[SimState], None]

# Effort noise per joint goes from its at-rest level (joint standing) to its in-motion level over this speed,
# linearly: the threshold below which benchmarks/effort_noise.py counts a real joint as not moving.
NOISE_RAMP_RAD_S = 0.05


class SimRobot:
    def __init__(self, spec: ArmSpec, *, q0_rad: Sequence[float], tick_s: float = 0.008,
                 time_scale: float = 1.0, friction: FrictionParams | None = None,
                 noise_nm: float | Sequence[float] = 0.0, seed: int | None = None,
                 payload: PayloadTruth | None = None, stop_decel_rad_s2: float = 3.0,
                 effects: PhysicsEffects | None = None, noise_rest_nm: float | Sequence[float] | None = None,
                 ripple_seed: int | None = None, session: int = 0, noise_per_move: bool = False):
        """``noise_nm``: each joint's effort noise (standard deviation) while it moves; ``noise_rest_nm``: while
        it stands (None: the same). A real drive's torque fluctuates more in motion (gear mesh, control activity)
        than at rest: measured 2-5x on a UR10e (docs/sources.md, "Effort noise of the simulated UR5e").
        ``ripple_seed``: fixes the gears' ripple phases (None: ``seed``), so two instances standing for the same
        arm (an empty and a loaded run recorded apart) share its gears while their noise differs.
        ``session``: which power-on of this arm it is (``SimulatedCell`` counts them per robot state). A real
        drive's noise does not repeat when the controller restarts; 0 draws what a seeded robot always drew, each
        later session its own noise (effort, angles, timestamps) from the same seed, on the same arm and gears.
        ``noise_per_move``: each commanded motion (``move_joints``, ``follow_path``) draws its noise (effort, angles,
        timestamps) from generators of its own, seeded by (seed, session, motion number); standing ticks draw from
        the session's streams. The streams are drawn once per tick, so without it which noise a motion's samples get
        depends on the tick at which its command arrived: with the clock elastic, on how loaded the host was
        (tests/test_verify.py's flake under two busy loops). With it, a seeded session's motions repeat their noise
        exactly however late the commands come; the noise is as white and Gaussian either way, as a real drive's.
        A robot YAML turns it on unless ``simulation.noise_per_move: false``; built directly, as the accuracy
        benchmark's arms are, a SimRobot draws per tick, so their kept cases keep their draws."""
        self.spec = spec
        self.physics = ArmPhysics(spec, payload)
        self.tick_s = float(tick_s)
        self.time_scale = float(time_scale)
        self.effects = effects or PhysicsEffects()
        friction = friction or FrictionParams()
        if any(self.effects.coulomb_asymmetry):
            friction = dataclasses.replace(friction, asymmetry=np.asarray(self.effects.coulomb_asymmetry))
        self.friction = friction
        self.noise_nm = np.broadcast_to(np.asarray(noise_nm, float), (6,)).copy()
        self.noise_rest_nm = (self.noise_nm.copy() if noise_rest_nm is None
                              else np.broadcast_to(np.asarray(noise_rest_nm, float), (6,)).copy())
        self._noise_flat = bool(np.array_equal(self.noise_nm, self.noise_rest_nm))
        self.rng = np.random.default_rng(seed if seed is None or not session else [int(seed), 20, int(session)])
        # angle noise and timestamp jitter draw from their own stream: switching them on leaves the
        # effort noise of a seeded robot unchanged
        self._sensor_rng = np.random.default_rng(
            None if seed is None else [int(seed), 10] + ([int(session)] if session else []))
        self._ripple_phases = ripple_phases(seed if ripple_seed is None else ripple_seed)
        self._seed, self._session = seed, int(session)
        self.noise_per_move = bool(noise_per_move)
        self._motion_rngs: tuple[np.random.Generator, np.random.Generator] | None = None
        self._temperature_c = np.full(6, self.effects.temperature_ref_c)
        self._tau_gear = np.zeros(6)  # last tick's torque through the gears (start of the elastic fixed point)
        self._cable_rest: np.ndarray | None = None
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
            else:
                # behind (a saturated or loaded host): still hand the GIL over every tick, or the agent's
                # stream reader and watchdog, sharing this process, wait behind the clock thread
                time.sleep(0)
                if delay < -0.05:  # slow simulated time down rather than burst
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
        fx = self.effects
        temps = self.temperatures_c()
        factor = fx.friction_factor(temps) if fx.friction_per_c else 1.0
        cable = fx.tool_cable.active and self.physics.payload is not None
        q_zero = q - fx.zero_offset
        tau_gear = self._tau_gear
        for _ in range(2 if fx.elastic else 1):  # link angle = motor angle − τ/k: a fixed point, 2 passes
            q_link = q_zero - fx.compliance_rad_per_nm * tau_gear if fx.elastic else q_zero  # (rigid: − 0·τ)
            load = self.physics.rigid_torque(q_link, qd, qdd)
            if cable:
                load = load + fx.tool_cable.torque(q_link, self._cable_rest_for(q_link))
            tau_gear = load + self.friction.torque(qd, load, factor)
        self._tau_gear = tau_gear
        tau = tau_gear
        if fx.ripple.active:
            tau = tau + fx.ripple.torque(q, tau_gear, self._ripple_phases)
        rng, sensor_rng = (self._motion_rngs if self._path is not None and self._motion_rngs is not None
                           else (self.rng, self._sensor_rng))
        tau = fx.quantise(tau + rng.normal(0.0, 1.0, 6) * self.noise_level_nm(qd))
        q_rep = q + fx.angle_noise(sensor_rng)
        t_rep = t + fx.jitter(sensor_rng, self.tick_s)
        return SimState(t_rep, q_rep, qd.copy(), qdd.copy(), tau, self._path is not None, self._estop,
                        self._protective, self._servo, self._move_id, t_true=t, q_true=q.copy(),
                        q_link=q_link.copy(), temperature_c=temps)

    def noise_level_nm(self, qd: np.ndarray) -> np.ndarray:
        """Each joint's effort noise σ at joint speeds ``qd``: the at-rest level standing, the in-motion level
        from ``NOISE_RAMP_RAD_S`` on, linear between (one random draw per tick either way, so a seeded robot
        without an at-rest level draws exactly as before)."""
        if self._noise_flat:  # no at-rest level: rest + 0·ramp is rest (asked every tick)
            return self.noise_rest_nm.copy()
        ramp = np.minimum(np.abs(np.asarray(qd, float)) / NOISE_RAMP_RAD_S, 1.0)
        return self.noise_rest_nm + (self.noise_nm - self.noise_rest_nm) * ramp

    def _cable_rest_for(self, q_link: np.ndarray) -> np.ndarray:
        """The wrist angles where the tool cable is relaxed: given, or where the tool was mounted
        (``set_payload`` notes them; a robot built with a payload takes its first angles)."""
        if self.effects.tool_cable.rest_rad is not None:
            return np.asarray(self.effects.tool_cable.rest_rad)
        if self._cable_rest is None:
            self._cable_rest = np.asarray(q_link[3:6], float).copy()
        return self._cable_rest

    def temperatures_c(self) -> np.ndarray:
        """Joint temperatures the friction model uses: the set ones, warmer by tool_warmup_c with a tool on."""
        warm = self.effects.tool_warmup_c if self.physics.payload is not None else 0.0
        return self._temperature_c + warm

    def set_joint_temperatures(self, values_c: Sequence[float]) -> None:
        """Set the joints' temperatures (°C, 6 values; without the tool warm-up)."""
        with self._lock:
            self._temperature_c = np.broadcast_to(np.asarray(values_c, float), (6,)).copy()

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
            self._path = JointPath(self._q_now(), target, self._t, speed_rad_s, accel_rad_s2,
                                   self._max_speed, self._max_accel)
            self._move_id += 1
            self._start_motion_noise()
            return self._path.t_end - self._t

    def _start_motion_noise(self) -> None:
        """With ``noise_per_move`` (and a seed): the new motion's own noise generators (caller holds the lock)."""
        if self.noise_per_move and self._seed is not None:
            key = [int(self._seed), self._session, self._move_id]
            self._motion_rngs = (np.random.default_rng(key + [20]), np.random.default_rng(key + [10]))

    def _q_now(self) -> np.ndarray:
        """The controller's exact (noise-free) joint angles now (caller holds the lock)."""
        q = self._state.q_true
        return np.asarray(self._state.q if q is None else q, float).copy()

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
            path = make_path(self._t, self._q_now())
            if np.max(np.abs(np.asarray(path.at(self._t)[0]) - self._q_now())) > 1e-6:
                raise SimRefused("trajectory does not start at the current joint angles")
            self._path = path
            self._move_id += 1
            self._start_motion_noise()
            return path.t_end - self._t

    def stop(self, decel_rad_s2: float | None = None) -> None:
        with self._lock:
            if self._path is not None:
                self._path.stop_at(self._t, decel_rad_s2 or self.stop_decel_rad_s2)

    def set_payload(self, payload: PayloadTruth | None) -> None:
        """Mount (or remove, None) the tool. A tool cable without given rest angles relaxes where it is mounted."""
        with self._lock:
            self.physics.set_payload(payload)
            here = self._state.q_link
            self._cable_rest = None if here is None else np.asarray(here[3:6], float).copy()

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
