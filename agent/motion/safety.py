"""The safety gate: the only code that may command robot motion.

It validates the whole plan (joint limits with margin, speed cap, floor and reach
box along every joint-space path, slow first approach) before the first move, and
then executes exactly the approved moves, in order, nothing else.

The first move may run at travel speed instead of the approach speed only when the gate was given our
own resting-pose record (``recording.resting_pose``) and the angles the plan starts from match it: the
arm then stands where our last completed motion left it, not somewhere unknown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver
from payload_agent.errors import SafetyError
from payload_agent.motion import workspace
from payload_agent.motion.planner import (MAX_SINGLE_MOVE_RAD, Move, Plan, first_move_percent, move_duration_s,
                                          turned_to)
from payload_agent.recording.resting_pose import RestingPose


@dataclass
class Verdict:
    ok: bool
    problems: list[str] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)

    def describe(self) -> str:
        approach_only = len(self.problems) == 1 and self.problems[0].startswith(APPROACH_UNKNOWN)
        head = ("SAFE: all checks passed" if self.ok else
                "plan OK, approach NOT CHECKED (give --from-deg or --connect; `run` checks it before moving)"
                if approach_only else "REFUSED")
        lines = [head] + [f"  ok  {c}" for c in self.checks] + [f"  !!  {p}" for p in self.problems]
        return "\n".join(lines)


APPROACH_UNKNOWN = "current joint angles unknown"


class SafetyGate:
    def __init__(self, config: Config, resting: RestingPose | None = None):
        """``resting``: where our last completed motion left the arm; a plan starting there may make its first
        move at travel speed (checked against the start angles at every ``check``)."""
        self.config = config
        self.resting = resting
        self.kin = config.robot.kinematics
        self.safety = config.safety
        self._approved: tuple[Move, ...] | None = None
        self._next = 0

    # -- validation -------------------------------------------------------------------------
    def check(self, plan: Plan, start_q: np.ndarray | None) -> Verdict:
        """Check every move of the plan; ``start_q`` (current angles) is needed to check the approach path."""
        s, robot = self.safety, self.config.robot
        problems: list[str] = []
        vmax = robot.max_joint_speed_rad_s
        cap = vmax * s.max_speed_percent / 100.0
        first_pct, first_what = s.approach_speed_percent, "approach cap"
        if self.resting is not None and start_q is not None:
            if self.resting.matches(start_q):
                first_pct = first_move_percent(self.config, True)
                first_what = "travel speed from our own resting pose"
            else:
                first_what = (f"approach cap (the arm stands {math.degrees(self.resting.offset_rad(start_q)):.2f}° "
                              "from the recorded resting pose)")
        first_cap = vmax * first_pct / 100.0
        wrist_pct = s.max_speed_percent if s.max_wrist_speed_percent is None else s.max_wrist_speed_percent
        wrist_cap = vmax * wrist_pct / 100.0
        wrist_accel = self.config.wrist_accel_rad_s2
        wrist_accel_key = ("safety.max_wrist_accel_deg_s2" if s.max_wrist_accel_rad_s2 is not None
                           else "robot.max_joint_accel_deg_s2; safety.max_wrist_accel_deg_s2 not set")
        margin = s.joint_limit_margin_rad
        if not plan.moves:
            problems.append("the plan has no moves")
        elif plan.moves[0].kind != "approach":
            problems.append("the first move must be the slow approach move")
        prev = None if start_q is None else np.asarray(start_q, float)
        if prev is None:
            problems.append(APPROACH_UNKNOWN + ": the approach path cannot be checked")
        for i, m in enumerate(plan.moves):
            tgt = np.asarray(m.target_rad, float)
            where = f"move {i + 1} ({m.label})"
            for j, (v, (lo, hi)) in enumerate(zip(tgt, robot.joint_limits_rad)):
                if not (lo + margin <= v <= hi - margin):
                    problems.append(f"{where}: joint {j + 1} target {math.degrees(v):.1f}° outside limits "
                                    f"[{math.degrees(lo):.0f}, {math.degrees(hi):.0f}]° less "
                                    f"{math.degrees(margin):.0f}° margin")
            if m.kind == "wrist" and m.speed_rad_s > wrist_cap * (1 + 1e-9):
                problems.append(f"{where}: wrist move at {100 * m.speed_rad_s / vmax:.2f} % above the cap "
                                f"{wrist_pct:g} % (safety.max_wrist_speed_percent; the inertia part's moves are "
                                "never slowed down to fit)")
            elif m.kind != "wrist" and m.speed_rad_s > cap * (1 + 1e-9):
                problems.append(f"{where}: speed {100 * m.speed_rad_s / vmax:.2f} % above the cap "
                                f"{s.max_speed_percent:g} %")
            if i == 0 and m.speed_rad_s > first_cap * (1 + 1e-9):
                problems.append(f"{where}: first move at {100 * m.speed_rad_s / vmax:.2f} %, {first_what} is "
                                f"{first_pct:g} %")
            if m.kind == "wrist" and not 0 < m.accel_rad_s2 <= wrist_accel * (1 + 1e-9):
                problems.append(f"{where}: wrist move accelerating at {math.degrees(m.accel_rad_s2):.1f}°/s², outside "
                                f"(0, {math.degrees(wrist_accel):.1f}]°/s² ({wrist_accel_key})")
            elif m.kind != "wrist" and not 0 < m.accel_rad_s2 <= robot.max_joint_accel_rad_s2 * (1 + 1e-9):
                problems.append(f"{where}: acceleration {math.degrees(m.accel_rad_s2):.1f}°/s² outside "
                                f"(0, {math.degrees(robot.max_joint_accel_rad_s2):.1f}]°/s² (robot.max_joint_accel_deg_s2)")
            problems.extend(self._driver_limit_problems(where, m))
            if prev is None:
                prev = tgt
                continue
            if np.max(np.abs(tgt - prev)) > MAX_SINGLE_MOVE_RAD:
                j = int(np.argmax(np.abs(tgt - prev)))
                problems.append(f"{where}: joint {j + 1} turns {math.degrees(abs(tgt[j] - prev[j])):.0f}° in one "
                                f"move (more than {math.degrees(MAX_SINGLE_MOVE_RAD):.0f}°), from "
                                f"{math.degrees(prev[j]):.1f}° to {math.degrees(tgt[j]):.1f}°")
            out = workspace.outside_on_path(s, self.kin, prev, tgt)
            if out is not None:
                problems.append(f"{where}: {out[1]}" + ("; narrow procedure.sweep_deg or change procedure.base_deg, "
                                                        "or check safety.floor_z_mm" if out[0] == "floor" else ""))
            prev = tgt
        checks = [
            f"{len(plan.moves)} moves within joint limits less {math.degrees(margin):.0f}° margin",
            f"every speed <= {s.max_speed_percent:g} % of {math.degrees(vmax):.0f}°/s; first move <= "
            f"{first_pct:g} %" + (f" ({first_what})" if first_pct > s.approach_speed_percent else "")
            + (f"; wrist moves <= {wrist_pct:g} % and <= {math.degrees(wrist_accel):.1f}°/s²" if plan.wrist_moves
               else ""),
            f"{workspace.body(s)} above floor z = {1000 * s.floor_z_m:.0f} mm and inside the reach box along every "
            "path" + ("" if s.tool_radius_m else " (the tool not checked: no safety.tool_radius_mm)"),
        ]
        return Verdict(not problems, problems, checks if not problems else [])

    def check_after(self, plan: Plan, previous: Plan, previous_start_q: np.ndarray | None = None) -> Verdict:
        """The check of ``plan`` started where ``previous`` ends (its last target; ``previous_start_q`` where it
        has no moves): a session's second run (the loaded run after the empty run, the reference after the empty
        run of ``calibrate``), checked with the first before anything moves. The problems say so."""
        end = previous.moves[-1].target_rad if previous.moves else previous_start_q
        verdict = self.check(plan, None if end is None else np.asarray(end, float))
        verdict.problems = [f"started where the run before it ends: {p}" for p in verdict.problems]
        return verdict

    def check_loop(self, plan: Plan) -> Verdict:
        """Whether the plan closes its loop: what starting the next run where this one ends (the plan turned to
        that end pose as a session turns it, ``planner.turned_to``) adds to the problems it has anyway (from its own
        first target). A plan that does not close cannot record the empty and the loaded run in one session, and
        each run needs the arm moved back within reach of its start first."""
        if not plan.moves:
            return self.check(plan, None)
        end = np.asarray(plan.moves[-1].target_rad, float)
        anyway = set(self.check(plan, np.asarray(plan.moves[0].target_rad, float)).problems)
        verdict = self.check(turned_to(self.config, plan, end), end)
        verdict.problems = [p for p in verdict.problems if p not in anyway]
        verdict.ok = not verdict.problems
        return verdict

    def _driver_limit_problems(self, where: str, m: Move) -> list[str]:
        """A move above what the driver's move command accepts (``DriverOptions.command_limits``)."""
        opts = self.config.driver_options
        lim = type(opts).command_limits if opts is not None else None
        out = []
        driver = self.config.driver_type
        if lim is not None and lim.max_joint_speed_rad_s is not None and m.speed_rad_s > lim.max_joint_speed_rad_s:
            out.append(f"{where}: joint speed {m.speed_rad_s:.4f} rad/s ({math.degrees(m.speed_rad_s):.1f}°/s) above the "
                       f"{lim.max_joint_speed_rad_s:g} rad/s the {driver} driver's move command accepts ({lim.source}); "
                       "lower the move's speed percent")
        if lim is not None and lim.max_joint_accel_rad_s2 is not None and m.accel_rad_s2 > lim.max_joint_accel_rad_s2:
            out.append(f"{where}: joint acceleration {m.accel_rad_s2:.3f} rad/s² above the {lim.max_joint_accel_rad_s2:g} "
                       f"rad/s² the {driver} driver's move command accepts ({lim.source})")
        return out

    def approve(self, plan: Plan, start_q: np.ndarray | None) -> Verdict:
        verdict = self.check(plan, start_q)
        if not verdict.ok:
            raise SafetyError("the safety gate refused the plan:\n" + "\n".join(f"  - {p}" for p in verdict.problems))
        self._approved = plan.moves
        self._next = 0
        self._start_q = np.asarray(start_q, float)
        return verdict

    # -- execution --------------------------------------------------------------------------
    def execute(self, driver: Driver, move: Move, current_q: np.ndarray) -> None:
        """Run the next approved move; anything else (skipped, repeated, changed, robot moved) is refused."""
        if self._approved is None:
            raise SafetyError("no approved plan: call approve() with the whole plan first")
        if self._next >= len(self._approved) or self._approved[self._next] is not move:
            raise SafetyError(f"move {move.label!r} is not the next approved move")
        expected_start = self._start_q if self._next == 0 else np.asarray(self._approved[self._next - 1].target_rad)
        drift = float(np.max(np.abs(np.asarray(current_q) - expected_start)))
        if drift > math.radians(0.5):
            raise SafetyError(f"before {move.label!r}: the robot is {math.degrees(drift):.2f}° away from where the "
                              f"approved plan expects it; refusing to move")
        expected = move_duration_s(np.asarray(current_q), np.asarray(move.target_rad), move.speed_rad_s,
                                   move.accel_rad_s2)
        timeout = expected * self.safety.motion_timeout_factor + 5.0
        self._next += 1
        driver.move_joints(move.target_rad, move.speed_rad_s, move.accel_rad_s2, timeout_s=timeout)

    def redo_last_sweep(self, driver: Driver, current_q: np.ndarray) -> None:
        """Take the arm back along the sweep just run to its start, so that the sweep can run again.

        Only a sweep may be redone, only from its end, and only back along its own joint-space
        segment (a path this gate has already checked) at the sweep's own approved speed.
        """
        if self._approved is None or self._next == 0:
            raise SafetyError("no sweep has run yet: nothing to redo")
        idx = self._next - 1
        move = self._approved[idx]
        if move.sweep is None:
            raise SafetyError(f"{move.label!r} is not a sweep: only sweeps are redone")
        start = self._start_q if idx == 0 else np.asarray(self._approved[idx - 1].target_rad)
        drift = float(np.max(np.abs(np.asarray(current_q) - np.asarray(move.target_rad))))
        if drift > math.radians(0.5):
            raise SafetyError(f"cannot redo {move.label!r}: the robot is {math.degrees(drift):.2f}° away from the "
                              "sweep's end")
        expected = move_duration_s(np.asarray(current_q), start, move.speed_rad_s, move.accel_rad_s2)
        self._next = idx
        driver.move_joints(tuple(float(v) for v in start), move.speed_rad_s, move.accel_rad_s2,
                           timeout_s=expected * self.safety.motion_timeout_factor + 5.0)
