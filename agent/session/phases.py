"""One phase of a session (the empty-flange or the loaded run): every move of the approved plan, recorded.

Motion goes only through the safety gate. Before the first move and at every sweep start the
flange pose the controller reports is compared with the YAML's kinematics. Every sweep's
samples go to the recorder with the driver's stream statistics; a sweep whose stream had a
gap is never marked complete: it is redone where the user allowed retries, otherwise the
phase aborts. Any exception, Ctrl-C or supervision trip stops the robot; what was recorded
stays on disk. The resting-pose record (``recording.resting_pose``) is removed before the first
move and written again when the phase completed with the arm standing at its last target, or as the
path of the move under way when a communication failure made our supervision stop it.
"""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver
from payload_agent.errors import (CommunicationError, MotionAbortedError, PayloadAgentError, SafetyError,
                                  SupervisionTrip, Terminated)
from payload_agent.motion.crosscheck import compare_pose
from payload_agent.motion.planner import Plan
from payload_agent.motion.safety import SafetyGate
from payload_agent.output.stop_text import stop_sentence
from payload_agent.recording import resting_pose
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.rundata import MOUNT_KEY
from payload_agent.recording.state import RobotState

SAMPLE_WAIT_S = 5.0
SETTLE_WAIT_S = 15.0  # after a move: the stream may lag the finished reply (a loaded host, a fast simulation)
SETTLED_RAD = math.radians(0.05)


def joint_temperatures(driver: Driver) -> list[float] | None:
    """Joint temperatures, °C, where the controller reports them (friction depends on them)."""
    try:
        temps = driver.joint_temperatures_c()
    except PayloadAgentError:
        return None
    return None if temps is None else [round(float(t), 2) for t in temps]


def check_kinematics(config: Config, driver: Driver, q: np.ndarray, where: str):
    """Refuse (SafetyError) when the controller's flange pose disagrees with the YAML's FK at ``q``.

    Returns the PoseCheck, or None for a driver whose controller reports no pose.
    """
    if not driver.reports_flange_pose:
        return None
    pose = driver.flange_pose()
    if pose is None:
        return None
    check = compare_pose(config.robot.kinematics, q, pose, config.safety.pose_tolerance_m,
                         config.safety.pose_tolerance_rad)
    if not check.ok:
        raise SafetyError(f"kinematic cross-check failed {where}: the robot YAML does not describe this robot. "
                          f"{check.describe()} Nothing moved after this check.")
    return check


class PhaseRunner:
    """Holds the live connection for one session's phases; every exit path stops the robot."""

    def __init__(self, config: Config, driver: Driver, gate: SafetyGate, recorder: RunRecorder,
                 out: Callable[[str], None], progress=None, retry_sweeps: int = 0):
        self.config, self.driver, self.gate, self.recorder, self.out = config, driver, gate, recorder, out
        self.progress = progress
        self.retry_sweeps = retry_sweeps
        self.pose_checks = 0

    def sink(self, sample) -> None:
        self.recorder.sink(sample)
        if self.progress is not None:
            self.progress.on_sample(sample)

    def current_q(self, after: float | None = None, near: tuple[float, ...] | None = None) -> np.ndarray:
        """Latest joint angles; with ``after`` (monotonic time), from a sample received after it, and with
        ``near``, from one at those angles (the stream may lag the motion-finished reply). Without
        ``after``, a sample fresh enough for the driver to move on (after a pause of the stream, e.g. the
        simulated tool change, the newest may be too old and the driver would refuse to move blind)."""
        if after is None:
            after = time.monotonic() - 0.5 * self.driver.gap_limit_s
        deadline = time.monotonic() + (SAMPLE_WAIT_S if near is None else SETTLE_WAIT_S)
        while True:
            s = self.driver.wait_sample(max(0.0, deadline - time.monotonic()), after=after)
            if near is None or np.max(np.abs(np.asarray(s.q) - near)) < SETTLED_RAD:
                return np.asarray(s.q, float)
            if time.monotonic() > deadline:
                off = np.abs(np.asarray(s.q, float) - np.asarray(near, float))
                j = int(np.argmax(off))
                raise CommunicationError(
                    f"the joint angles did not settle at the move's target within {SETTLE_WAIT_S:.0f} s after "
                    f"the controller reported it finished: joint {j + 1} streams {math.degrees(s.q[j]):.4f} deg, "
                    f"target {math.degrees(near[j]):.4f} deg (the newest sample, controller time {s.t_ctrl} s)")
            time.sleep(0.002)

    def recorded_start(self) -> np.ndarray:
        """The joint angles of a sample received after the move's file was opened, before the move goes out.

        The file then starts with the arm at rest where the move starts, and the safety gate checks that
        very sample against the plan. Without the wait a reader thread the scheduler holds back while the
        move is sent (RTDE's receive interface keeps only the newest package) would join late, and the
        recording would begin wherever the arm had got to (seen: a sweep recorded from 2° past its start).
        """
        return self.current_q(after=time.monotonic())

    def run_phase(self, name: str, plan: Plan, resume: bool = False) -> None:
        start_q = self.current_q()
        self.gate.approve(plan, start_q)  # the approach path starts wherever the robot stands now
        check_kinematics(self.config, self.driver, start_q, f"before the {name} run")
        state_root = RobotState.for_config(self.config).root
        resting_pose.clear(state_root)  # the arm is about to leave it
        # where the loaded phase first starts is where the tool went on: a tool cable's rest (systematics.cable_spring)
        mount = {} if resume or name != "loaded" else {MOUNT_KEY: [float(v) for v in start_q]}
        self.recorder.begin_phase(name, resume, joint_temperatures_c={"start": joint_temperatures(self.driver)}, **mount)
        if self.progress is not None:
            self.progress.begin_phase(name)
        n = len(plan.moves)
        retries_left = self.retry_sweeps
        try:
            i = 0
            while i < n:
                move = plan.moves[i]
                q_now = self.current_q()
                if move.sweep is not None:
                    check_kinematics(self.config, self.driver, q_now, f"at the start of sweep {move.label}")
                    self.pose_checks += 1
                if move.recorded_name is not None:  # a sweep, or a wrist move of the inertia part
                    self.driver.begin_stats()
                    self.recorder.begin_sweep(move)
                    q_now = self.recorded_start()
                self.out(f"  [{name}] {i + 1}/{n} {move.label}")
                if self.progress is not None:
                    self.progress.begin_move(i + 1, move, q_now)
                self.gate.execute(self.driver, move, q_now)
                self.current_q(after=time.monotonic(), near=move.target_rad)  # the stream caught up with the move
                if self.progress is not None:
                    self.progress.end_move()
                if move.recorded_name is not None:
                    self.recorder.freeze_sweep()  # first: the statistics then count every sample the file holds
                    stats = self.driver.end_stats()
                    if stats is not None and stats.gaps:
                        self.recorder.end_sweep("gap", stats.to_json())
                        if move.sweep is None:  # a wrist move with a hole is left out of the inertia fit
                            i += 1
                            continue
                        if retries_left <= 0:
                            raise SupervisionTrip(
                                f"sweep {move.label} has a hole in its sample stream (largest gap "
                                f"{1000 * stats.largest_gap_s:.0f} ms); it was not kept as complete. "
                                "Pass --retry-sweeps N to redo such sweeps.")
                        retries_left -= 1
                        self.out(f"  [{name}] sweep {move.label} had a stream gap of "
                                 f"{1000 * stats.largest_gap_s:.0f} ms: redoing it ({retries_left} retries left)")
                        self.gate.redo_last_sweep(self.driver, self.current_q())
                        self.current_q(after=time.monotonic(), near=plan.moves[i - 1].target_rad if i else None)
                        continue
                    self.recorder.end_sweep("complete", None if stats is None else stats.to_json())
                i += 1
        except BaseException as exc:
            self.stop_robot()
            if isinstance(exc, CommunicationError) and n:  # our supervision stopped it on this move's path
                try:
                    resting_pose.record(state_root, plan.moves[i - 1].target_rad if i else start_q,
                                        self.recorder.run_dir, plan.moves[min(i, n - 1)].target_rad)
                except OSError:
                    pass  # no record: the next session approaches slowly, as after any other stop
            if self.progress is not None:
                self.progress.close()
            self.recorder.freeze_sweep()
            stats = self.driver.end_stats()
            self.recorder.end_sweep("aborted", None if stats is None else stats.to_json())
            report = getattr(exc, "stop_report", None) or self.driver.last_stop_report
            self.recorder.end_phase(f"aborted: {stop_sentence(exc)}", None if report is None else report.to_json())
            if isinstance(exc, KeyboardInterrupt):
                how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted by the operator (Ctrl-C)"
                raise MotionAbortedError(f"{how}; the robot was stopped, recorded data kept in "
                                         f"{self.recorder.run_dir}") from None
            raise
        self.recorder.end_phase("complete", joint_temperatures_end=joint_temperatures(self.driver))
        if n:
            resting_pose.record(state_root, self.current_q(near=plan.moves[-1].target_rad), self.recorder.run_dir)

    def stop_robot(self) -> None:
        """Stop the move this session commanded, if one may still run (the driver sends nothing otherwise)."""
        try:
            self.driver.stop()
        except Exception:
            pass

