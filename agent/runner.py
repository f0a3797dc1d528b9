"""One identification run: connect, check, move through the approved plan, record, analyse.

Motion only ever goes through the SafetyGate. Any exception, Ctrl-C or lost
connection stops the robot; what was recorded stays in the run folder.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Callable

import numpy as np

from payload_agent import __version__
from payload_agent.analysis import deltas_for, quality_checks, solve_all
from payload_agent.config import Config, config_snapshot
from payload_agent.drivers.base import Driver
from payload_agent.drivers.registry import driver_class
from payload_agent.errors import (CommunicationError, MotionAbortedError, PayloadAgentError, RobotNotReadyError)
from payload_agent.planner import Plan, expected_durations, make_plan
from payload_agent.recorder import RunRecorder
from payload_agent.results import RunResult, format_table
from payload_agent.safety import SafetyGate

SAMPLE_WAIT_S = 5.0
SETTLED_RAD = math.radians(0.05)


@dataclass
class RunOptions:
    unattended: bool = False
    assume_yes: bool = False  # interactive, but the plan is accepted without asking
    result_path: Path | None = None
    solver: str | None = None
    out: Callable[[str], None] = print
    ask: Callable[[str], str] = input
    on_cell: Callable[[object], None] | None = None  # tests: sees the SimulatedCell once it runs


@dataclass
class RunOutcome:
    run_dir: Path
    result: RunResult | None
    truth: dict | None = None
    timings: dict[str, float] = field(default_factory=dict)


def make_driver(config: Config, options: dict | None = None) -> Driver:
    cls = driver_class(config.driver_type)
    return cls(options if options is not None else config.driver,
               max_joint_speed_rad_s=config.robot.max_joint_speed_rad_s)


def describe_plan(plan: Plan, durations: list[float]) -> str:
    lines = [f"Plan: procedure {plan.procedure.name}, {len(plan.moves)} moves per run"]
    for i, (m, d) in enumerate(zip(plan.moves, durations), 1):
        tgt = ", ".join(f"{math.degrees(v):7.2f}" for v in m.target_rad)
        dur = "   ?  " if math.isnan(d) else f"{d:6.1f}"
        lines.append(f"  {i:2d}. {m.kind:8s} {m.label:22s} [{tgt}] deg  {math.degrees(m.speed_rad_s):6.2f} deg/s "
                     f"{dur} s")
    total = sum(d for d in durations if not math.isnan(d))
    lines.append(f"  robot time per run: {total:.1f} s")
    return "\n".join(lines)


class _Session:
    """Holds the live connection; every exit path stops the robot."""

    def __init__(self, config: Config, driver: Driver, gate: SafetyGate, recorder: RunRecorder, out):
        self.config, self.driver, self.gate, self.recorder, self.out = config, driver, gate, recorder, out

    def current_q(self, after: float | None = None, near: tuple[float, ...] | None = None) -> np.ndarray:
        """Latest joint angles; with ``after`` (monotonic time), wait for a sample received after it,
        and with ``near``, for one at those angles (the stream may lag the motion-finished reply)."""
        deadline = time.monotonic() + SAMPLE_WAIT_S
        while True:
            s = self.recorder.last_sample
            if s is not None and (after is None or s.t_recv > after) and (
                    near is None or np.max(np.abs(np.asarray(s.q) - near)) < SETTLED_RAD):
                return np.asarray(s.q, float)
            if self.driver.stream_error is not None:
                raise CommunicationError(f"sample stream ended: {self.driver.stream_error}")
            if time.monotonic() > deadline:
                raise CommunicationError(f"no joint sample from the controller for {SAMPLE_WAIT_S:.0f} s")
            time.sleep(0.005)

    def run_phase(self, name: str, plan: Plan) -> None:
        start_q = self.current_q()
        self.gate.approve(plan, start_q)  # the approach path starts wherever the robot stands now
        self.recorder.begin_phase(name)
        n = len(plan.moves)
        try:
            for i, move in enumerate(plan.moves, 1):
                q_now = self.current_q()
                if move.sweep is not None:
                    self.recorder.begin_sweep(move)
                self.out(f"  [{name}] {i}/{n} {move.label}")
                self.gate.execute(self.driver, move, q_now)
                done = time.monotonic()
                self.current_q(after=done, near=move.target_rad)  # the stream has caught up with the move
                if move.sweep is not None:
                    self.recorder.end_sweep("complete")
        except BaseException as exc:
            self.stop_robot()
            self.recorder.end_sweep("aborted")
            self.recorder.end_phase(f"aborted: {type(exc).__name__}: {exc}")
            if isinstance(exc, KeyboardInterrupt):
                raise MotionAbortedError("interrupted by the operator (Ctrl-C); the robot was stopped, "
                                         f"recorded data kept in {self.recorder.run_dir}") from None
            raise
        self.recorder.end_phase("complete")

    def stop_robot(self) -> None:
        try:
            self.driver.stop()
        except Exception:
            pass


def run_identification(config: Config, opts: RunOptions) -> RunOutcome:
    out = opts.out
    plan = make_plan(config)
    gate = SafetyGate(config)
    cell = None
    driver_options = dict(config.driver)
    if config.simulation is not None:
        from payload_agent.simulation import SimulatedCell

        cell = SimulatedCell(config).start()
        driver_options = cell.options
        if opts.on_cell is not None:
            opts.on_cell(cell)
        out(f"Simulated {config.simulation.arm} controller on {driver_options.get('host')} "
            f"(time x{config.simulation.time_scale:g}); payload truth {cell.truth_json}")
    t0 = time.monotonic()
    driver = make_driver(config, driver_options)
    recorder = None
    try:
        driver.connect()
        info = driver.identify()
        state = driver.state()
        out(f"Connected: {info.vendor} {info.model}, firmware {info.firmware}; mode {state.mode}")
        if state.fault:
            raise RobotNotReadyError(f"the robot is not ready: {state.fault}. Clear it on the pendant and retry.")
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}"
        suffix = 1
        while run_dir.exists():
            suffix += 1
            run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}-{suffix}"
        recorder = RunRecorder(run_dir, {
            "format": "payload-agent-run/1", "software_version": __version__, "robot": config.robot.name,
            "config_source": config.source, "config": config_snapshot(config),
            "controller": {"vendor": info.vendor, "model": info.model, "firmware": info.firmware,
                           "serial": info.serial},
            "effort_unit": driver.effort_unit, "gains_nm_per_unit": list(config.effort.gains_nm_per_unit),
            "procedure": plan.procedure.name, "plan_fingerprint": plan.fingerprint(),
            "plan": [m.to_json() for m in plan.moves],
            "simulation_truth": cell.truth_json if cell else None,
        })
        driver.start_stream(recorder.sink)
        session = _Session(config, driver, gate, recorder, out)
        start_q = session.current_q()
        verdict = gate.check(plan, start_q)
        out(describe_plan(plan, expected_durations(plan, start_q)))
        out("Safety gate: " + verdict.describe())
        if not verdict.ok:
            gate.approve(plan, start_q)  # raises SafetyError with every problem listed
        if not (opts.unattended or opts.assume_yes):
            answer = opts.ask("Run the empty-flange and the loaded run now? The robot will move. [y/N] ")
            if answer.strip().lower() not in ("y", "yes"):
                raise MotionAbortedError("the operator declined; nothing moved")
        for phase, mounted in (("empty", False), ("loaded", True)):
            _prepare_tool(phase, mounted, cell, opts, out)
            session.run_phase(phase, plan)
        t_motion = time.monotonic() - t0
        driver.stop_stream()
        if driver.stream_error is not None:
            raise CommunicationError(f"the sample stream failed: {driver.stream_error}")
    except BaseException:
        try:
            driver.stop()
        except Exception:
            pass
        raise
    finally:
        try:
            driver.close()
        finally:
            if cell is not None:
                cell.close()
    result = analyse(config, recorder.run_dir, solver=opts.solver)
    recorder.update(finished_utc=datetime.now().astimezone().isoformat(timespec="seconds"))
    if opts.result_path is not None:
        result.write(opts.result_path)
    out(format_table(result, cell.truth_json if cell else None))
    out(f"Result written to {recorder.run_dir / 'result.json'}")
    return RunOutcome(recorder.run_dir, result, cell.truth_json if cell else None,
                      {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion})


def _prepare_tool(phase: str, mounted: bool, cell, opts: RunOptions, out) -> None:
    if cell is not None:
        cell.mount_tool(mounted)
        out(f"Simulated tool change: tool {'mounted' if mounted else 'removed'}")
        return
    if opts.unattended:
        raise RobotNotReadyError(f"the {phase} run needs the tool {'mounted' if mounted else 'removed'}, "
                                 "which an unattended run cannot ask for")
    what = "Mount the tool" if mounted else "Remove the tool (empty flange)"
    opts.ask(f"{what}, keep clear of the robot, then press Enter to continue. ")


def analyse(config: Config, run_dir: Path, solver: str | None = None, baseline_dir: Path | None = None) -> RunResult:
    notes: list[str] = []
    deltas = deltas_for(run_dir, np.asarray(config.effort.gains_nm_per_unit), baseline_dir, notes=notes)
    kin = config.robot.kinematics
    primary, others = solve_all(deltas, kin, solver or config.procedure.solver)
    primary.notes.extend(notes)
    quality = quality_checks(deltas, kin, primary)
    result = RunResult(config.robot.name, str(run_dir), primary, others, quality=quality)
    result.write(Path(run_dir) / "result.json")
    return result
