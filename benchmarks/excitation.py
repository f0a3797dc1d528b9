"""Excitation trajectories for the dynamic-model baseline, and recording them on a SimRobot.

The paper's comparison method (Gao, Zhao, Li 2025, §3.4) drives joints 4–6 along a
5th-order finite Fourier series (the parameterisation of Swevers, Ganseman, Tükel,
de Schutter and Van Brussel, IEEE Trans. Robotics and Automation 13(5), 1997, the
paper's ref. [17]), optimised so that the regressor W(q, q̇, q̈) is well conditioned;
joints 1–3 hold a fixed pose. Per moving joint i, with ω_f = 2π/T:

    q_i(t) = q0_i + Σ_{l=1..5} [ a_il/(ω_f l)·sin(ω_f l t) − b_il/(ω_f l)·cos(ω_f l t) ]

Start and end at rest: Σ_l a_il = 0 gives q̇(0) = 0, Σ_l l·b_il = 0 gives q̈(0) = 0, and
the series is periodic, so after a whole number of periods the arm is back at the start
pose at rest. q0_i is chosen so that q(0) is the start pose. The coefficients are scaled
down until the speed, acceleration and excursion bounds hold everywhere (checked on a
fine grid). Instead of the paper's genetic algorithm, a seeded random search keeps the
candidate whose (column-normalised) payload regressor has the smallest condition number.

This is simulator-only: the EC66's controller accepts no such trajectory (the paper's
reason for its own method), which is why the agent itself has no excitation planner.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.fakes.offline import step_until_still
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers.dynamic import ExcitationRecord
from payload_agent.solvers.regressor import payload_regressor

HARMONICS = 5
PERIOD_S = 10.0
PERIODS = 3
EXCITED_JOINTS = (3, 4, 5)  # 0-based: joints 4, 5, 6
# bounds: the safety envelope's speed cap (25 % of 144 °/s) and half the configured max
# acceleration (300 °/s², configs/sim-ec66.yaml); excursion keeps the wrist clear of its limits
MAX_SPEED_RAD_S = math.radians(0.25 * 144.0)
MAX_ACCEL_RAD_S2 = math.radians(0.5 * 300.0)
MAX_EXCURSION_RAD = math.radians(90.0)


@dataclass(frozen=True)
class FourierTrajectory:
    """Finite Fourier series per joint; rows of ``a``/``b`` are zero for joints held still."""

    q_start: np.ndarray  # (6,) rad, also the end pose
    a: np.ndarray  # (6, H) rad/s
    b: np.ndarray  # (6, H) rad/s
    period_s: float
    periods: int

    @property
    def duration_s(self) -> float:
        return self.period_s * self.periods

    @property
    def _w(self) -> float:
        return 2.0 * math.pi / self.period_s

    def _offset(self) -> np.ndarray:
        lw = self._w * np.arange(1, self.a.shape[1] + 1)
        return self.q_start + (self.b / lw).sum(axis=1)

    def evaluate(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, q̇, q̈ at times ``tau`` (s since the start, clipped to [0, duration]): each (n, 6)."""
        tau = np.clip(np.atleast_1d(np.asarray(tau, float)), 0.0, self.duration_s)
        lw = self._w * np.arange(1, self.a.shape[1] + 1)  # (H,)
        ph = np.outer(tau, lw)  # (n, H)
        s, c = np.sin(ph), np.cos(ph)
        q = self._offset() + s @ (self.a / lw).T - c @ (self.b / lw).T
        qd = c @ self.a.T + s @ self.b.T
        qdd = (-s * lw) @ self.a.T + (c * lw) @ self.b.T
        return q, qd, qdd


class TrajectoryPath:
    """Adapter: a FourierTrajectory started at simulated time t0, as ``SimRobot.follow_path`` wants it."""

    def __init__(self, traj: FourierTrajectory, t0: float):
        self.traj = traj
        self.t0 = float(t0)
        self.t_end = self.t0 + traj.duration_s
        self._stop: tuple[float, np.ndarray, np.ndarray, float] | None = None
        # per-tick evaluation without re-deriving the series (the simulator calls at() every tick)
        self._lw = traj._w * np.arange(1, traj.a.shape[1] + 1)
        self._off = traj._offset()
        self._a_lw, self._b_lw = traj.a / self._lw, traj.b / self._lw

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._stop is not None:
            ts, qs, vs, dur = self._stop
            s = min(max(t - ts, 0.0), dur)
            frac = 1.0 - s / dur if dur > 0 else 0.0
            q = qs + vs * (s - 0.5 * s * s / dur) if dur > 0 else qs
            return q, vs * frac, (-vs / dur if 0 < s < dur else np.zeros(6))
        if t >= self.t_end:
            return self.traj.q_start.copy(), np.zeros(6), np.zeros(6)
        ph = self._lw * (t - self.t0)
        s, c = np.sin(ph), np.cos(ph)
        a, b = self.traj.a, self.traj.b
        return (self._off + self._a_lw @ s - self._b_lw @ c, a @ c + b @ s,
                a @ (-s * self._lw) + b @ (c * self._lw))

    def stop_at(self, t: float, decel: float) -> None:
        """Ramp every joint's speed down linearly, all reaching zero together at ``decel`` for the fastest."""
        if t >= self.t_end:
            return
        q, qd, _ = self.at(t)
        dur = float(np.max(np.abs(qd))) / decel
        self._stop = (t, q, qd, dur)
        self.t_end = t + dur


def _bounded(a: np.ndarray, b: np.ndarray, q_start: np.ndarray, period_s: float, max_speed: float,
             max_accel: float, max_excursion: float) -> FourierTrajectory:
    """Enforce the rest conditions, then scale each joint down to its speed/accel/excursion bounds."""
    H = a.shape[1]
    l = np.arange(1, H + 1)
    a = a - a.mean(axis=1, keepdims=True)  # Σ a_l = 0
    b = b - np.outer(b @ l, l) / (l @ l)  # Σ l·b_l = 0
    traj = FourierTrajectory(np.asarray(q_start, float), a, b, period_s, 1)
    tau = np.linspace(0.0, period_s, 2001)
    q, qd, qdd = traj.evaluate(tau)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.nanmin(np.stack([max_speed / np.max(np.abs(qd), axis=0),
                                max_accel / np.max(np.abs(qdd), axis=0),
                                max_excursion / np.max(np.abs(q - q_start), axis=0)]), axis=0)
    k = np.where(np.isfinite(k), k, 0.0) * 0.999
    return FourierTrajectory(traj.q_start, a * k[:, None], b * k[:, None], period_s, 1)


def condition_number(kin: Kinematics, traj: FourierTrajectory, samples: int = 400) -> float:
    """cond of the column-normalised payload regressor stacked over all joints, over one period."""
    q, qd, qdd = traj.evaluate(np.linspace(0.0, traj.period_s, samples, endpoint=False))
    W = payload_regressor(kin, q, qd, qdd).reshape(-1, 10)
    norms = np.linalg.norm(W, axis=0)
    return float(np.linalg.cond(W / np.where(norms > 0, norms, 1.0)))


def design_trajectory(kin: Kinematics, q_start: Sequence[float], *, joints: Sequence[int] = EXCITED_JOINTS,
                      harmonics: int = HARMONICS, period_s: float = PERIOD_S, periods: int = PERIODS,
                      max_speed_rad_s: float = MAX_SPEED_RAD_S, max_accel_rad_s2: float = MAX_ACCEL_RAD_S2,
                      max_excursion_rad: float = MAX_EXCURSION_RAD, candidates: int = 30,
                      seed: int = 0) -> FourierTrajectory:
    """The best-conditioned of ``candidates`` random bounded Fourier trajectories (seeded)."""
    rng = np.random.default_rng(seed)
    q_start = np.asarray(q_start, float)
    best, best_cond = None, math.inf
    for _ in range(candidates):
        a = np.zeros((6, harmonics))
        b = np.zeros((6, harmonics))
        a[list(joints)] = rng.normal(size=(len(joints), harmonics))
        b[list(joints)] = rng.normal(size=(len(joints), harmonics))
        traj = _bounded(a, b, q_start, period_s, max_speed_rad_s, max_accel_rad_s2, max_excursion_rad)
        cond = condition_number(kin, traj)
        if cond < best_cond:
            best, best_cond = traj, cond
    assert best is not None
    return FourierTrajectory(best.q_start, best.a, best.b, period_s, periods)


def default_start(kin: Kinematics, wrist_deg: Sequence[float] = (90.0, -90.0, 0.0)) -> np.ndarray:
    """Joints 1–3 held with link 2 vertical and link 3 horizontal (the joint-3 sweep's start), base 0."""
    from payload_agent.model.arm_geometry import ArmGeometry

    geo = ArmGeometry(kin, 0.0)
    q2, q3 = geo.joints_for(math.pi / 2, 0.0)
    return np.array([0.0, q2, q3, *np.radians(wrist_deg)])


def record_excitation(robot: SimRobot, traj: FourierTrajectory, *, torque_scale: np.ndarray | None = None,
                      approach_speed_rad_s: float = math.radians(14.4), approach_accel_rad_s2: float = 1.0,
                      settle_ticks: int = 5) -> tuple[ExcitationRecord, float]:
    """Move to the start (not recorded), follow the trajectory tick by tick, return the record and motion time.

    Time in the record counts from the trajectory's start, so an empty and a loaded run of
    the same trajectory share one time base. Effort is N·m × ``torque_scale`` (drive gain error).
    """
    scale = np.ones(6) if torque_scale is None else np.asarray(torque_scale, float)
    here = robot.snapshot()
    if np.max(np.abs((here.q if here.q_true is None else here.q_true) - traj.q_start)) > 1e-9:  # exact, not noisy, angles
        robot.move_joints(traj.q_start, approach_speed_rad_s, approach_accel_rad_s2)
        while robot.step().moving:
            pass
    t0 = robot.now()
    robot.follow_path(lambda t, q: TrajectoryPath(traj, t))
    states = [robot.snapshot(), *step_until_still(robot, settle_ticks)]
    t = np.array([s.t for s in states]) - t0
    q = np.array([s.q for s in states])
    tau = np.array([s.torque_nm for s in states]) * scale
    return ExcitationRecord(t, q, tau, f"sim:excitation:{robot.spec.name}"), traj.duration_s
