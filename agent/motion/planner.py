"""Procedure + robot config -> a Plan: the exact list of PTP joint moves, each labelled.

The plan is pure data; nothing here talks to a robot. The safety gate validates it
whole before the first move.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass

import numpy as np

from payload_agent.model.arm_geometry import ArmGeometry
from payload_agent.configuration.config import Config
from payload_agent.errors import PlanError
from payload_agent.types import SweepKey
from payload_agent.configuration.procedure import Procedure, load_procedure
from payload_agent.configuration.wrist_procedure import WristProcedure, load_wrist_procedure


@dataclass(frozen=True)
class Move:
    label: str
    kind: str  # "approach" | "travel" | "sweep" | "wrist"
    target_rad: tuple[float, ...]
    speed_rad_s: float
    accel_rad_s2: float
    sweep: SweepKey | None = None
    wrist: str | None = None  # a recorded wrist move's name (inertia), e.g. "w1-a-j6-fwd"

    @property
    def recorded_name(self) -> str | None:
        """The name its samples are kept under (a sweep or a wrist move), None for moves not recorded."""
        return self.sweep.name if self.sweep is not None else self.wrist

    def to_json(self) -> dict:
        d = {"label": self.label, "kind": self.kind, "target_deg": [round(math.degrees(v), 6) for v in self.target_rad],
             "speed_deg_s": round(math.degrees(self.speed_rad_s), 6),
             "accel_deg_s2": round(math.degrees(self.accel_rad_s2), 6)}
        if self.sweep:
            d["sweep"] = {"pose": self.sweep.pose, "joint": self.sweep.joint, "direction": self.sweep.direction,
                          "speed_percent": self.sweep.speed_percent}
        if self.wrist:
            d["wrist"] = self.wrist
        return d


@dataclass(frozen=True)
class Plan:
    procedure: Procedure
    moves: tuple[Move, ...]

    @property
    def sweeps(self) -> list[Move]:
        return [m for m in self.moves if m.kind == "sweep"]

    @property
    def wrist_moves(self) -> list[Move]:
        return [m for m in self.moves if m.kind == "wrist"]

    def fingerprint(self) -> str:
        """Changes whenever any target, speed or sweep changes (a stored baseline depends on it)."""
        data = [m.to_json() for m in self.moves if m.kind != "approach"]
        return hashlib.sha256(json.dumps([self.procedure.fingerprint, data], sort_keys=True).encode()).hexdigest()[:16]


def move_duration_s(start: np.ndarray, target: np.ndarray, speed: float, accel: float) -> float:
    """Duration of a synchronized trapezoidal PTP move led by the joint with the longest travel."""
    dist = float(np.max(np.abs(np.asarray(target) - np.asarray(start))))
    if dist == 0:
        return 0.0
    if dist < speed * speed / accel:
        return 2.0 * math.sqrt(dist / accel)
    return dist / speed + speed / accel


_WRISTS: dict[tuple, dict[str, np.ndarray]] = {}


def make_plan(config: Config, procedure: Procedure | None = None) -> Plan:
    proc = procedure or load_procedure(config.procedure.name)
    pc = config.procedure
    robot = config.robot
    geo = ArmGeometry(robot.kinematics, math.radians(pc.base_deg))
    lo, hi = math.radians(pc.sweep_from_deg), math.radians(pc.sweep_to_deg)
    vmax, amax = robot.max_joint_speed_rad_s, robot.max_joint_accel_rad_s2
    sweep_speed = vmax * pc.speed_percent / 100.0
    travel_speed = vmax * pc.travel_speed_percent / 100.0
    accel = amax * pc.accel_percent / 100.0
    margin = config.safety.joint_limit_margin_rad
    wrist_limits = [(a + margin, b - margin) for a, b in robot.joint_limits_rad[3:]]

    # the wrist solutions (the slow part: a numerical solve per pose) depend on the poses, the base angle,
    # the kinematics and the limits only, not on the sweep range or speeds: kept for the next plan
    wkey = (proc.fingerprint, tuple(proc.poses), pc.base_deg, repr(robot.dh), tuple(wrist_limits))
    wrists: dict[str, np.ndarray] = {}
    if wkey in _WRISTS:
        wrists = {k: v.copy() for k, v in _WRISTS[wkey].items()}
    prefer = np.zeros(3)
    for name, pose in proc.poses.items():
        if name in wrists:
            continue
        q2, q3 = geo.joints_for(0.0, 0.0)
        R = geo.tool_rotation(np.array([geo.base, q2, q3, 0, 0, 0]), pose.tool_x, pose.tool_z)
        wrists[name] = prefer = geo.wrist_for(q2, q3, R, wrist_limits, prefer)  # next pose: least wrist travel
    if len(_WRISTS) > 64:
        _WRISTS.clear()
    _WRISTS[wkey] = {k: v.copy() for k, v in wrists.items()}

    def target(pose: str, joint: int, elev: float) -> np.ndarray:
        e2, e3 = (elev, elev) if joint == 2 else (math.pi / 2, elev)
        q2, q3 = geo.joints_for(e2, e3)
        q = np.array([geo.base, q2, q3, *wrists[pose]])
        # the wrist holds still relative to link 3, so the tool orientation must hold along the sweep
        spec = proc.poses[pose]
        if np.max(np.abs(robot.kinematics.flange(q)[:3, :3] - geo.tool_rotation(q, spec.tool_x, spec.tool_z))) > 1e-9:
            raise PlanError(f"pose {pose}: tool orientation is not constant along the joint-{joint} sweep")
        return q

    moves: list[Move] = []
    first = True
    for sw in proc.sweeps:
        start, end = target(sw.pose, sw.joint, lo), target(sw.pose, sw.joint, hi)
        label = f"{sw.pose}-j{sw.joint}"
        if first:
            moves.append(Move(f"approach {label} start", "approach", tuple(start),
                              vmax * config.safety.approach_speed_percent / 100.0, accel))
            first = False
        else:
            moves.append(Move(f"to {label} start", "travel", tuple(start), travel_speed, accel))
        moves.append(Move(f"{label} up", "sweep", tuple(end), sweep_speed, accel,
                          SweepKey(sw.pose, sw.joint, "up", pc.speed_percent)))
        if pc.bidirectional:
            moves.append(Move(f"{label} down", "sweep", tuple(start), sweep_speed, accel,
                              SweepKey(sw.pose, sw.joint, "down", pc.speed_percent)))
    if pc.inertia:
        moves.extend(wrist_moves(config, load_wrist_procedure(pc.inertia), geo, wrist_limits, moves[-1].target_rad))
    return Plan(proc, tuple(moves))


def _nearest_turn(w: np.ndarray, prefer: np.ndarray, limits: list[tuple[float, float]]) -> np.ndarray:
    """The same wrist orientation with each joint shifted by whole turns to lie nearest ``prefer``, within limits."""
    out = np.array(w, float)
    for k, (lo, hi) in enumerate(limits):
        turns = [out[k] + 2 * math.pi * n for n in range(-2, 3)]
        inside = [v for v in turns if lo <= v <= hi]
        if inside:
            out[k] = min(inside, key=lambda v: abs(v - prefer[k]))
    return out


def wrist_moves(config: Config, wp: WristProcedure, geo: ArmGeometry, wrist_limits: list[tuple[float, float]],
                after: tuple[float, ...]) -> list[Move]:
    """The inertia part, after the move to ``after``: per wrist move of ``wp``, a travel to its start (where the arm
    is not there already), then there and back, both recorded.

    Speed and acceleration are the wrist procedure's own; the safety gate refuses them by move name
    when the YAML's caps forbid them (they are never slowed down to fit).
    """
    robot, pc = config.robot, config.procedure
    speed = robot.max_joint_speed_rad_s * wp.speed_percent / 100.0
    accel = robot.max_joint_accel_rad_s2 * wp.accel_percent / 100.0
    travel = robot.max_joint_speed_rad_s * pc.travel_speed_percent / 100.0
    travel_accel = robot.max_joint_accel_rad_s2 * pc.accel_percent / 100.0
    q2, q3 = geo.joints_for(0.0, 0.0)
    q2e, q3e = geo.joints_for(math.radians(wp.elevation_deg[0]), math.radians(wp.elevation_deg[1]))
    wrists, prefer = {}, np.asarray(after[3:], float)
    for name, pose in wp.poses.items():  # each orientation: the least wrist travel from the one before
        R = geo.tool_rotation(np.array([geo.base, q2, q3, 0, 0, 0]), pose.tool_x, pose.tool_z)
        wrists[name] = prefer = _nearest_turn(geo.wrist_for(q2, q3, R, wrist_limits, prefer), prefer, wrist_limits)
    out: list[Move] = []
    for k, mv in enumerate(wp.moves):
        start = np.array([geo.base, q2e, q3e, *wrists[mv.pose]])
        end = start.copy()
        start[mv.joint - 1] += math.radians(mv.from_deg)
        end[mv.joint - 1] += math.radians(mv.to_deg)
        name = f"w{k + 1}-{mv.pose}-j{mv.joint}"
        if np.max(np.abs(np.asarray(out[-1].target_rad if out else after) - start)) > 1e-9:
            out.append(Move(f"to {name} start", "travel", tuple(start), travel, travel_accel))
        out.append(Move(f"{name} fwd", "wrist", tuple(end), speed, accel, wrist=f"{name}-fwd"))
        out.append(Move(f"{name} back", "wrist", tuple(start), speed, accel, wrist=f"{name}-back"))
    return out


def expected_durations(plan: Plan, start_q: np.ndarray | None) -> list[float]:
    """Per move, in seconds; the approach move's duration needs the robot's current angles."""
    out = []
    prev = None if start_q is None else np.asarray(start_q, float)
    for m in plan.moves:
        tgt = np.asarray(m.target_rad)
        out.append(float("nan") if prev is None else move_duration_s(prev, tgt, m.speed_rad_s, m.accel_rad_s2))
        prev = tgt
    return out


def remaining_plan(config: Config, plan: Plan, done: set[str]) -> Plan:
    """The moves that record only the sweeps not in ``done`` (sweep names), for resuming a run.

    Each remaining sweep is preceded by a move to its start (at travel speed) unless the arm is
    already there; the first move is the slow approach. The safety gate checks the result whole,
    like any plan.
    """
    pc, robot = config.procedure, config.robot
    travel = robot.max_joint_speed_rad_s * pc.travel_speed_percent / 100.0
    approach = robot.max_joint_speed_rad_s * config.safety.approach_speed_percent / 100.0
    moves: list[Move] = []
    for i, m in enumerate(plan.moves):
        if m.recorded_name is None or m.recorded_name in done:
            continue
        start = plan.moves[i - 1].target_rad
        if not moves or moves[-1].target_rad != start:
            kind, speed = ("approach", approach) if not moves else ("travel", travel)
            moves.append(Move(f"to {m.recorded_name} start", kind, start, speed,
                              min(m.accel_rad_s2, robot.max_joint_accel_rad_s2 * pc.accel_percent / 100.0)))
        moves.append(m)
    return Plan(plan.procedure, tuple(moves))
