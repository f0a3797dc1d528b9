"""Procedure + robot config -> a Plan: the exact list of PTP joint moves, each labelled.

The plan is pure data; nothing here talks to a robot. The safety gate validates it
whole before the first move.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
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

# The most any joint may turn in one move (the safety gate refuses more): a plan's own moves, and the approach of a
# run that starts where the last one ended (the plan "closes its loop"), stay within it.
MAX_SINGLE_MOVE_RAD = math.radians(200.0)


@dataclass(frozen=True)
class Move:
    label: str
    kind: str  # "approach" | "travel" | "sweep" | "wrist"
    target_rad: tuple[float, ...]
    speed_rad_s: float
    accel_rad_s2: float
    sweep: SweepKey | None = None
    wrist: str | None = None  # a recorded wrist move's name (inertia), e.g. "w1-c-j456-fwd" (joints 4, 5, 6 together)

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
        """Changes whenever any target, speed or sweep changes (a stored baseline depends on it); not when a joint's
        targets all shift by whole turns (``turned_to``): the arm stands the same way, so it weighs the same."""
        data = [m.to_json() for m in self.moves if m.kind != "approach"]
        for d in data:
            d["target_deg"] = [round((v + 180.0) % 360.0 - 180.0, 4) + 0.0 for v in d["target_deg"]]
        return hashlib.sha256(json.dumps([self.procedure.fingerprint, data], sort_keys=True).encode()).hexdigest()[:16]


def move_duration_s(start: np.ndarray, target: np.ndarray, speed: float, accel: float) -> float:
    """Duration of a synchronized trapezoidal PTP move led by the joint with the longest travel."""
    dist = float(np.max(np.abs(np.asarray(target) - np.asarray(start))))
    if dist == 0:
        return 0.0
    if dist < speed * speed / accel:
        return 2.0 * math.sqrt(dist / accel)
    return dist / speed + speed / accel


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

    q2, q3 = geo.joints_for(0.0, 0.0)
    rotations = {name: geo.tool_rotation(np.array([geo.base, q2, q3, 0, 0, 0]), pose.tool_x, pose.tool_z)
                 for name, pose in proc.poses.items()}
    wrists: dict[str, np.ndarray] = {}

    def chain(prefer: np.ndarray) -> None:  # each pose: the least wrist travel from the one before
        for name, R in rotations.items():
            wrists[name] = prefer = geo.wrist_for(q2, q3, R, wrist_limits, prefer)

    chain(np.zeros(3))
    if len(rotations) > 1:  # again from the second pose: where the first is free (joints 4 and 6 in line) it keeps
        chain(wrists[list(rotations)[1]])  # the second's joint 4, so the wrist does not turn between them

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
        moves.extend(wrist_moves(config, load_wrist_procedure(pc.inertia), geo, wrist_limits, moves[-1].target_rad,
                                 close_to=moves[0].target_rad))
    moves.extend(closing_travel(moves, travel_speed, accel))
    return turned_to(config, Plan(proc, tuple(moves)), np.zeros(len(robot.joint_limits_rad)))  # the first pose near 0


def closing_travel(moves: list[Move], speed: float, accel: float) -> list[Move]:
    """A travel move that ends the plan where the next run's approach can reach its start, or none.

    A run may start where the last one ended (the empty run, then the loaded run; the next session), and its
    approach turns no joint more than ``MAX_SINGLE_MOVE_RAD``. Where the plan ends farther than that from its
    first target, it ends with one travel move back to a pose it has already stood in (a move's target) from
    which the first target lies within reach: of those the travel move itself can reach, the one nearest the
    first target (the approach runs at the slow approach speed), ties to the latest. None found: no move, and
    the safety gate refuses any session that would start the plan where it ends (``SafetyGate.check_after``).
    """
    if len(moves) < 2:
        return []
    first, end = moves[0].target_rad, moves[-1].target_rad
    if _largest_turn(end, first) <= MAX_SINGLE_MOVE_RAD:
        return []
    reachable = [(_largest_turn(m.target_rad, first), -i, m) for i, m in enumerate(moves[:-1])
                 if _largest_turn(end, m.target_rad) <= MAX_SINGLE_MOVE_RAD
                 and _largest_turn(m.target_rad, first) <= MAX_SINGLE_MOVE_RAD]
    if not reachable:
        return []
    back = min(reachable, key=lambda r: (round(r[0], 9), r[1]))[2]
    return [Move(f"return toward {moves[0].label.removeprefix('approach ')} (to {back.label.removeprefix('to ')})",
                 "travel", back.target_rad, speed, accel)]


def turned_to(config: Config, plan: Plan, start_q: np.ndarray | None) -> Plan:
    """The same plan with each joint's targets shifted by the whole turns that bring its first target nearest
    where the robot stands, where every target stays within the joint limits less the margin.

    The plan itself must not depend on where a run starts (a stored baseline is matched to it), but a joint at
    +180° or -180° is the same pose, and which of them the robot reaches first by a short turn does: from J4 at
    90°, -180° is a 270° approach the safety gate refuses, +180° is 90°.
    """
    if start_q is None or not plan.moves:
        return plan
    margin = config.safety.joint_limit_margin_rad
    targets = np.array([m.target_rad for m in plan.moves], float)
    shift = np.zeros(targets.shape[1])
    for j, (lo, hi) in enumerate(config.robot.joint_limits_rad):
        fits = [2 * math.pi * k for k in range(-2, 3)
                if np.all(targets[:, j] + 2 * math.pi * k >= lo + margin) and np.all(targets[:, j] + 2 * math.pi * k <= hi - margin)]
        if fits:
            shift[j] = min(fits, key=lambda d: (abs(targets[0, j] + d - start_q[j]), abs(d)))
    if not shift.any():
        return plan
    moves = tuple(dataclasses.replace(m, target_rad=tuple(float(v) for v in np.asarray(m.target_rad) + shift))
                  for m in plan.moves)
    return Plan(plan.procedure, moves)


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
                after: tuple[float, ...], close_to: tuple[float, ...] | None = None) -> list[Move]:
    """The inertia part, after the move to ``after``: per wrist move of ``wp``, a travel to its start (where the arm
    is not there already), then there and back, both recorded.

    Speed and acceleration are the wrist procedure's own (its accel_percent of ``Config.wrist_accel_rad_s2``); the
    safety gate refuses them by move name when the YAML's caps forbid them (they are never slowed down to fit).

    ``close_to``: the plan's first target. Each orientation's wrist angles are first the least travel from the one
    before; where the part would then end more than ``MAX_SINGLE_MOVE_RAD`` from ``close_to`` in some joint (the
    next run, starting where this one ends, could not approach its start), the whole-turn equivalents of the
    orientations' wrist angles that end nearest it are chosen instead (``_closing_turns``): the same orientations
    and the same recorded motion, only which way round the joints stand.
    """
    robot, pc = config.robot, config.procedure
    speed = robot.max_joint_speed_rad_s * wp.speed_percent / 100.0
    accel = config.wrist_accel_rad_s2 * wp.accel_percent / 100.0
    travel = robot.max_joint_speed_rad_s * pc.travel_speed_percent / 100.0
    travel_accel = robot.max_joint_accel_rad_s2 * pc.accel_percent / 100.0
    q2, q3 = geo.joints_for(0.0, 0.0)
    q2e, q3e = geo.joints_for(math.radians(wp.elevation_deg[0]), math.radians(wp.elevation_deg[1]))
    wrists, prefer = {}, np.asarray(after[3:], float)
    for name, pose in wp.poses.items():  # each orientation: the least wrist travel from the one before
        R = geo.tool_rotation(np.array([geo.base, q2, q3, 0, 0, 0]), pose.tool_x, pose.tool_z)
        wrists[name] = prefer = _nearest_turn(geo.wrist_for(q2, q3, R, wrist_limits, prefer), prefer, wrist_limits)

    def build(wrists: dict[str, np.ndarray]) -> list[Move]:
        out: list[Move] = []
        for k, mv in enumerate(wp.moves):
            start = np.array([geo.base, q2e, q3e, *wrists[mv.pose]])
            end = start.copy()
            for j, lo, hi in zip(mv.joints, mv.from_deg, mv.to_deg):
                start[j - 1] += math.radians(lo)
                end[j - 1] += math.radians(hi)
            name = f"w{k + 1}-{mv.pose}-{mv.label}"
            if np.max(np.abs(np.asarray(out[-1].target_rad if out else after) - start)) > 1e-9:
                out.append(Move(f"to {name} start", "travel", tuple(start), travel, travel_accel))
            out.append(Move(f"{name} fwd", "wrist", tuple(end), speed, accel, wrist=f"{name}-fwd"))
            out.append(Move(f"{name} back", "wrist", tuple(start), speed, accel, wrist=f"{name}-back"))
        return out

    out = build(wrists)
    if close_to is None or not out or _largest_turn(out[-1].target_rad, close_to) <= MAX_SINGLE_MOVE_RAD:
        return out
    return _closing_turns(build, wrists, after, close_to, wrist_limits) or out


def _largest_turn(a, b) -> float:
    """The largest joint travel of a PTP move from ``a`` to ``b``."""
    return float(np.max(np.abs(np.asarray(a, float) - np.asarray(b, float))))


def _closing_turns(build, wrists: dict[str, np.ndarray], after: tuple[float, ...], close_to: tuple[float, ...],
                   wrist_limits: list[tuple[float, float]]) -> list[Move] | None:
    """The inertia part (``build``) with each orientation's wrist joints shifted by whole turns (-1, 0, +1 each) so
    that it ends within ``MAX_SINGLE_MOVE_RAD`` of ``close_to``: of the choices whose every target lies within the
    limits and whose every move (the travels into and between the orientations included) turns no joint more than
    that, the one with the smallest largest turn (the closing move counted), then the least travel; None when none.
    A fixed enumeration order with ties to the first: the plan does not depend on where a run starts. With more
    than two orientations (3^9 and more choices) every orientation takes the same shift per joint (27 choices).
    """
    lo, hi = np.array(wrist_limits, float).T
    names = list(wrists)
    each = len(names) <= 2
    best, best_key = None, None
    for shifts in itertools.product((0, -1, 1), repeat=3 * len(names) if each else 3):
        turned = {n: wrists[n] + 2 * math.pi * np.array(shifts[3 * i:3 * i + 3] if each else shifts, float)
                  for i, n in enumerate(names)}
        moves = build(turned)
        targets = np.array([m.target_rad for m in moves], float)[:, 3:]
        if np.any(targets < lo - 1e-9) or np.any(targets > hi + 1e-9):
            continue
        steps = [_largest_turn(a, m.target_rad) for a, m in zip([after, *[m.target_rad for m in moves[:-1]]], moves)]
        key = (round(max(*steps, _largest_turn(moves[-1].target_rad, close_to)), 9), round(sum(steps), 9))
        if key[0] <= MAX_SINGLE_MOVE_RAD and (best_key is None or key < best_key):
            best, best_key = moves, key
    return best


def parked(config: Config, plan: Plan) -> Plan:
    """``plan`` ending with one more travel move back to its own first target (``calibrate --park``), unless it
    ends there already: the arm then waits for the tool change at the first pose of this plan, so a run of the same
    plan after it (one that reuses the calibration's empty run) starts with no approach, and the tool goes on (the
    rest of a cable's spring) at a pose of its own sweeps. An ordinary move of the plan, checked with the rest of it
    before the first move (a park the gate would refuse refuses the session), and recorded as our resting pose."""
    if len(plan.moves) < 2:
        return plan
    first, end = plan.moves[0].target_rad, plan.moves[-1].target_rad
    if _largest_turn(first, end) <= 1e-9:
        return plan
    pc, robot = config.procedure, config.robot
    label = plan.moves[0].label.removeprefix("approach ")
    park = Move(f"park at {label} (the plan's first pose)", "travel", first,
                robot.max_joint_speed_rad_s * pc.travel_speed_percent / 100.0,
                robot.max_joint_accel_rad_s2 * pc.accel_percent / 100.0)
    return dataclasses.replace(plan, moves=(*plan.moves, park))


def first_move_percent(config: Config, from_rest: bool) -> float:
    """The speed cap of a session's first move, % of the joints' top speed: the slow approach, because the arm may
    stand anywhere; travel speed (within ``safety.max_speed_percent``) when it stands at our own resting pose
    (``recording.resting_pose``), a pose our own approved plan reached. The safety gate enforces it."""
    s = config.safety
    if not from_rest:
        return s.approach_speed_percent
    return max(s.approach_speed_percent, min(config.procedure.travel_speed_percent, s.max_speed_percent))


def from_resting_pose(config: Config, plan: Plan) -> Plan:
    """``plan`` with its first (approach) move at the speed ``first_move_percent`` allows from our own resting pose;
    the caller has matched the live angles with the record, and the gate checks that again."""
    if not plan.moves or plan.moves[0].kind != "approach":
        return plan
    first = plan.moves[0]
    speed = config.robot.max_joint_speed_rad_s * first_move_percent(config, True) / 100.0
    label = "from the resting pose to " + first.label.removeprefix("approach ")
    return dataclasses.replace(plan, moves=(dataclasses.replace(first, label=label, speed_rad_s=speed),
                                            *plan.moves[1:]))


def robot_time_s(plan: Plan, start_q=None) -> float:
    """Robot time of the plan; its first move (the approach) only when ``start_q``, where the robot stands, is known."""
    return float(sum(d for d in expected_durations(plan, start_q) if not math.isnan(d)))


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
    like any plan. It ends where the whole plan ends (a travel move there, where one move reaches it), so that
    a run after it (the loaded run after redone empty sweeps) starts where the session's check expected it.
    """
    pc, robot = config.procedure, config.robot
    travel = robot.max_joint_speed_rad_s * pc.travel_speed_percent / 100.0
    approach = robot.max_joint_speed_rad_s * config.safety.approach_speed_percent / 100.0
    travel_accel = robot.max_joint_accel_rad_s2 * pc.accel_percent / 100.0
    moves: list[Move] = []
    for i, m in enumerate(plan.moves):
        if m.recorded_name is None or m.recorded_name in done:
            continue
        start = plan.moves[i - 1].target_rad
        if not moves or moves[-1].target_rad != start:
            kind, speed = ("approach", approach) if not moves else ("travel", travel)
            moves.append(Move(f"to {m.recorded_name} start", kind, start, speed, min(m.accel_rad_s2, travel_accel)))
        moves.append(m)
    end = plan.moves[-1].target_rad if plan.moves else None
    if moves and moves[-1].target_rad != end and _largest_turn(moves[-1].target_rad, end) <= MAX_SINGLE_MOVE_RAD:
        moves.append(Move(f"to where the plan ends ({plan.moves[-1].label})", "travel", end, travel, travel_accel))
    return Plan(plan.procedure, tuple(moves))
