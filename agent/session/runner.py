"""One session with the robot: connect, check, move through the approved plan, record, analyse, apply.

Three kinds of session share this path (``RunOptions.mode``):

- ``identify``: the loaded run, reusing the stored empty-flange baseline when it still
  fits; otherwise (interactive only) the empty run first, which then becomes the baseline;
- ``baseline``: the empty-flange run only, stored as the robot's baseline;
- ``calibrate``: an identification of a known reference payload, whose result fits the
  drive gains (``payload_agent.evaluation.calibration``).

Motion only ever goes through the SafetyGate. Any exception, Ctrl-C or lost
connection stops the robot; what was recorded stays in the run folder. Nothing is
written to the controller unless the quality gates passed and the operator asked for it.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Callable, TextIO

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver
from payload_agent.errors import (BaselineError, CommunicationError, DataError, MotionAbortedError, PayloadAgentError,
                                  QualityGateError, RobotNotReadyError, SafetyError)
from payload_agent.motion.planner import Plan, expected_durations, remaining_plan
from payload_agent.motion.safety import SafetyGate
from payload_agent.analysis.run_deltas import segment_phase
from payload_agent.evaluation.calibration import RUN_CALIBRATION, effective_calibration
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.state import RobotState
from payload_agent.session import baseline as baselines
from payload_agent.output.console import attach_run_log, detach_run_log
from payload_agent.output.plan_table import format_plan
from payload_agent.session.finish import RunOutcome, finish, write_run_report
from payload_agent.session.robot_lock import robot_lock
from payload_agent.session.connection import build_driver, identify_controller, motion_under_way, simulated_cell
from payload_agent.session.manifest import RunManifest, new_run_dir
from payload_agent.output.stop_text import stop_sentence
from payload_agent.session.phases import PhaseRunner, check_kinematics, joint_temperatures
from payload_agent.session.preflight import preflight
from payload_agent.session.resume import ResumeState, config_fingerprint, load_resume
from payload_agent.types import PayloadSetting

SAMPLE_WAIT_S = 5.0
MODES = ("identify", "baseline", "calibrate")


@dataclass
class RunOptions:
    mode: str = "identify"
    unattended: bool = False  # never prompt: fail where a person would have to be asked
    assume_yes: bool = False  # interactive, but the plan (and --apply) are accepted without asking
    apply: bool = False  # write the result to the controller (only when the quality gates pass)
    fresh_baseline: bool = False  # record the empty run in this session even if a stored one fits
    tool: str | None = None  # the operator's label for the mounted tool (history, report)
    reference: PayloadSetting | None = None  # calibrate: the known payload mounted for this run
    result_path: Path | None = None
    solver: str | None = None
    report: bool = True
    progress: bool | None = None  # live progress line; None: only when the output is a terminal
    out: Callable[[str], None] = print
    ask: Callable[[str], str] = input
    on_cell: Callable[[object], None] | None = None  # tests: sees the SimulatedCell once it runs
    cell: Any = None  # an already started SimulatedCell to use (left running afterwards)
    retry_sweeps: int = 0  # redo a sweep whose sample stream had a gap, up to this many times per phase
    resume: Path | None = None  # an incomplete run folder to finish (only its unfinished sweeps are recorded)
    detail: Callable[[str], None] | None = None  # per-move lines (the CLI shows them with -v); default: out
    progress_stream: TextIO | None = None  # where the live progress line is drawn (default sys.stdout)
    console: Any = None  # the CLI's console, if any (unused by the session itself)


def _phases_for(config: Config, opts: RunOptions, state: RobotState, current: baselines.BaselineInfo,
                out) -> tuple[list[tuple[str, bool]], baselines.BaselineInfo | None, bool]:
    """(phases to record, the stored baseline to use or None, store this session's empty run?)."""
    if opts.mode == "baseline":
        return [("empty", False)], None, True
    if opts.fresh_baseline:
        if opts.unattended and config.simulation is None:
            raise RobotNotReadyError("--fresh-baseline needs the tool removed and mounted again, "
                                     "which an unattended run cannot ask for")
        return [("empty", False), ("loaded", True)], None, True
    try:
        stored = baselines.require_valid(state, current, config.storage.baseline_max_age_days,
                                         config.storage.baseline_max_temperature_delta_c)
    except BaselineError as exc:
        if opts.unattended:
            raise
        out(f"{exc}\nThis session records the empty-flange run first and stores it as the new baseline.")
        return [("empty", False), ("loaded", True)], None, True
    temps = ""
    if stored.joint_temperatures_c and current.joint_temperatures_c:
        worst = max(abs(b - a) for a, b in zip(stored.joint_temperatures_c, current.joint_temperatures_c))
        temps = f", joint temperatures within {worst:.1f} °C of then"
    out(f"Using the stored empty-flange baseline of {stored.recorded_utc} ({state.baseline_dir}{temps}); "
        "only the loaded run is recorded.")
    return [("loaded", True)], stored, False


def run_identification(config: Config, opts: RunOptions) -> RunOutcome:
    """One session: connect, check, show the plan, move through it, record, analyse, apply."""
    if opts.mode not in MODES:
        raise ValueError(f"unknown mode {opts.mode!r}")
    if opts.mode == "calibrate" and opts.reference is None:
        raise PayloadAgentError("calibrate needs the reference payload (--known-mass, --known-cog)")
    # everything `plan` checks, once, before anything starts: the YAML, the plan and the safety gate's view of it,
    # the driver section and what the options need of it, the stored calibration
    plan = preflight(config, calibration=opts.mode == "identify",
                     apply=opts.apply and opts.mode == "identify").require().plan
    resume = None
    if opts.resume is not None:
        resume = load_resume(config, plan, opts.resume)
        opts = dataclasses.replace(opts, mode=resume.mode)
    command = {"identify": "run", "baseline": "baseline", "calibrate": "calibrate"}[opts.mode]
    with robot_lock(RobotState.for_config(config), command + (" --resume" if resume else ""), config.robot.name,
                    opts.out), simulated_cell(config, opts.cell) as cell:  # one session per robot, before connecting
        driver = build_driver(config, cell.options if cell else None)
        if cell is not None:
            if opts.on_cell is not None:
                opts.on_cell(cell)
            opts.out(f"Simulated {config.simulation.arm if config.simulation else ''} controller at "
                     f"{driver.describe_endpoint()}; payload truth {cell.truth_json}")
        return _run_connected(config, opts, plan, cell, driver, resume)


def _run_connected(config: Config, opts: RunOptions, plan: Plan, cell, driver: Driver,
                   resume: ResumeState | None) -> RunOutcome:
    out, detail = opts.out, opts.detail or opts.out
    gate = SafetyGate(config)
    state = RobotState.for_config(config)
    t0 = time.monotonic()
    recorder = log = None
    try:
        driver.connect()
        info, start_q, pose_check = _check_controller(config, opts, driver)
        if resume is None:
            current = baselines.describe_for(config, plan, info, source_run=Path("."),
                                             joint_temperatures_c=joint_temperatures(driver))
            phases, stored_info, store_empty = _phases_for(config, opts, state, current, out)
            todo = [(p, m, plan) for p, m in phases]
        else:
            resume.check_controller(info)
            phases = [(p, m) for p, m, _ in resume.phases]
            stored_info, store_empty = resume.stored_info, resume.store_empty
            todo = [(p, m, remaining_plan(config, plan, done)) for p, m, done in resume.phases]
            out(f"Resuming {resume.run_dir}: " + "; ".join(
                f"{p} run, {len(sub.sweeps)} of {len(plan.sweeps)} sweeps left" for p, _, sub in todo))
        shown = todo[0][2]
        durations = _show_and_confirm(config, opts, driver, gate, shown, start_q, phases)
        changing = len(phases) > 1 or opts.mode == "baseline"
        _prepare_tool(todo[0][0], todo[0][1], cell, opts, out, changing)  # asked before any folder exists
        recorder = _open_recorder(config, opts, plan, info, driver, state, cell, resume, phases, stored_info,
                                  store_empty, pose_check)
        log = attach_run_log(recorder.run_dir)
        out(f"Run folder: {recorder.run_dir}")
        phase_runner = PhaseRunner(config, driver, gate, recorder, detail,
                                   _make_progress(opts, config, plan, durations, [p for p, _ in phases]),
                                   retry_sweeps=opts.retry_sweeps)
        driver.start_stream(phase_runner.sink)
        for i, (phase, mounted, phase_plan) in enumerate(todo):
            if i > 0:
                _prepare_tool(phase, mounted, cell, opts, out, changing)
            phase_runner.run_phase(phase, phase_plan, resume=resume is not None)
            if phase == "empty":  # checked while the tool is still off: a bad sweep is redone now
                _check_empty_run(config, plan, recorder, phase_runner, opts.retry_sweeps, out)
        if phase_runner.progress is not None:
            phase_runner.progress.close()
        driver.stop_stream()
        t_motion = time.monotonic() - t0
        if driver.stream_error is not None:
            raise CommunicationError(f"the sample stream failed: {driver.stream_error}")
        if store_empty:
            stored = _store_baseline(config, plan, info, state, recorder)
            out(f"Empty-flange baseline stored in {stored}")
        if opts.mode == "baseline":
            recorder.mark_complete()
            return RunOutcome(recorder.run_dir, None, cell.truth_json if cell else None,
                              {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion})
        outcome = finish(config, opts, state, driver, recorder.run_dir, stored_info, cell)
        outcome.timings = {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion}
        recorder.mark_complete()
    except BaseException as exc:
        stop_sent = driver.stop()  # only motion this session commanded; a refusal before our first move sends nothing
        if recorder is not None:
            _mark_stopped(config, recorder, exc, opts, out, stop_sent)
        raise
    finally:
        driver.close()
        detach_run_log(log)
    if outcome.result is not None:
        from payload_agent.evaluation.quality import require_passed

        try:
            require_passed(outcome.result)
        except QualityGateError as exc:
            error = QualityGateError(f"{exc}\nData, result and report kept in {outcome.run_dir}")
            error.outcome, error.run_dir = outcome, outcome.run_dir
            raise error from None
    return outcome


def _check_controller(config: Config, opts: RunOptions, driver: Driver):
    """Identity, readiness, drive gains and the kinematic cross-check, before anything is shown or moved."""
    out = opts.out
    info = identify_controller(driver)
    ctl_state = driver.state()
    out(f"Connected: {info.vendor} {info.model}, firmware {info.firmware}"
        + (f" ({ctl_state.detail})" if ctl_state.detail else ""))
    if not ctl_state.motion_allowed:  # refuse before the plan is shown, not at the first move
        raise RobotNotReadyError(f"the robot is not ready: {ctl_state.reason}")
    busy = motion_under_way(driver, ctl_state)
    if busy:  # another session or the pendant's program: left alone, nothing is sent
        raise RobotNotReadyError(f"the robot is not ready: {busy}. Wait until it stands still (another session, "
                                 "a cell controller or the pendant's program may be running); this session sent "
                                 "nothing to the controller")
    first = driver.wait_sample(SAMPLE_WAIT_S)
    if opts.mode == "identify":
        from payload_agent.evaluation.calibration import effective_gains

        note = effective_gains(config)[1]  # also refuses a calibration that no longer fits, before moving
        if note is None and first.target_current is not None:  # UR: evaluation.controller_gains after the run
            note = ("the controller's own constants, fitted from its target_current / target_moment after the run "
                    "(nominal effort.gains_nm_per_unit where they do not determine a joint)")
        out(f"Drive gains: {note}" if note else "Drive gains: nominal (effort.gains_nm_per_unit); "
            "`payload-agent calibrate` with a known reference payload removes their error")
    start_q = np.asarray(first.q, float)
    pose_check = check_kinematics(config, driver, start_q, "before any motion")
    if pose_check is not None:
        out(f"Kinematic cross-check: YAML model and controller agree within "
            f"{1000 * pose_check.position_error_m:.1f} mm, {math.degrees(pose_check.rotation_error_rad):.2f}°")
    return info, start_q, pose_check


def _show_and_confirm(config: Config, opts: RunOptions, driver: Driver, gate: SafetyGate, plan: Plan,
                      start_q: np.ndarray, phases: list) -> list[float]:
    """Show the plan and the gate's verdict; refuse a failing plan; ask before the robot moves."""
    verdict = gate.check(plan, start_q)
    durations = expected_durations(plan, start_q)
    opts.out(format_plan(plan, durations))
    opts.out("Safety gate: " + verdict.describe())
    if not verdict.ok:
        gate.approve(plan, start_q)  # raises SafetyError with every problem listed
    _confirm_without_pose_check(config, driver, plan, opts)
    if not (opts.unattended or opts.assume_yes):
        what = " and ".join({"empty": "the empty-flange run", "loaded": "the loaded run"}[p] for p, _ in phases)
        answer = opts.ask(f"Record {what} now? The robot will move. [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            raise MotionAbortedError("the operator declined; nothing moved")
    return durations


def _open_recorder(config, opts, plan, info, driver, state, cell, resume, phases, stored_info, store_empty,
                   pose_check) -> RunRecorder:
    """The run folder: a new one with its manifest, or the resumed one."""
    if resume is not None:
        recorder = RunRecorder.reopen(resume.run_dir)
        recorder.mark_resumed()
        return recorder
    recorder = RunRecorder(new_run_dir(config, opts.mode, datetime.now().strftime("%Y%m%d-%H%M%S")), {
        **RunManifest(config, plan, opts.mode, baselines.controller_identity(info), driver.effort_unit,
                      opts.tool, None if stored_info is None else {"dir": str(state.baseline_dir),
                                                                  **stored_info.to_json()},
                      opts.reference, cell.truth_json if cell else None,
                      None if pose_check is None else pose_check.to_json()).to_json(),
        "config_fingerprint": config_fingerprint(config), "phases_planned": phases, "store_empty": store_empty,
        "solver": opts.solver or config.procedure.solver})  # `solve` redoes the run with the run's own solver
    if stored_info is not None:  # the run folder keeps its own copy: self-contained
        recorder.adopt_phase("empty", baselines.copy_into_run(state, stored_info, recorder.run_dir))
    if opts.mode != "baseline" and effective_calibration(config) is not None:  # what its analysis will use, from
        shutil.copyfile(state.gains_path, recorder.run_dir / RUN_CALIBRATION)  # the start: solve and --resume agree
    return recorder


def _mark_stopped(config: Config, recorder: RunRecorder, exc: BaseException, opts: RunOptions, out,
                  stop_sent: bool) -> None:
    """An aborted run: the manifest says why, how the arm was stopped and whether this session sent a stop
    (only for motion it commanded); a report shows what was recorded."""
    report = getattr(exc, "stop_report", None)
    why = stop_sentence(exc)  # a sentence, no exception class names (output/stop_text.py)
    recorder.mark_stopped(why, None if report is None else report.to_json(),
                          stop_sent or (report is not None and report.stop_sent_t is not None))
    try:
        exc.run_dir = recorder.run_dir
    except AttributeError:
        pass
    if opts.report:
        write_run_report(config, recorder.run_dir, None, out)


def _confirm_without_pose_check(config: Config, driver: Driver, plan: Plan, opts: RunOptions) -> None:
    """A controller that reports no flange pose: the YAML kinematics cannot be cross-checked.

    Interactive runs show the planned flange heights and ask; unattended runs need the
    explicit acknowledgement ``safety.unattended_without_pose_check: true``.
    """
    if driver.reports_flange_pose:
        return
    heights = [1000 * float(config.robot.kinematics.flange(m.target_rad)[2, 3]) for m in plan.moves]
    opts.out(f"This controller reports no flange pose: the YAML kinematics cannot be checked against the robot. "
             f"Planned flange heights {min(heights):.0f} to {max(heights):.0f} mm above the base "
             f"(floor at {1000 * config.safety.floor_z_m:.0f} mm); watch the first move.")
    if opts.unattended:
        if not config.safety.unattended_without_pose_check:
            raise SafetyError("safety.unattended_without_pose_check: this driver cannot cross-check the YAML "
                              "kinematics against the robot, so an unattended run needs this explicit "
                              "acknowledgement (true) in the robot YAML, after an attended run has shown the "
                              "kinematics are right")
        return
    if not opts.assume_yes:
        answer = opts.ask("Do the planned flange heights match the robot's surroundings? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            raise MotionAbortedError("the operator did not confirm the flange heights; nothing moved")


def _store_baseline(config: Config, plan: Plan, info, state: RobotState, recorder: RunRecorder) -> Path:
    """Store this session's empty run as the baseline, only if every one of its sweeps segments."""
    from payload_agent.evaluation.pipeline import check_baseline_segmentation

    check_baseline_segmentation(config, recorder.run_dir)  # DataError: nothing is stored
    temps = recorder.phase_info("empty").get("joint_temperatures_c", {}).get("end")
    return baselines.store_baseline(state, recorder.run_dir,
                                    baselines.describe_for(config, plan, info, recorder.run_dir,
                                                           joint_temperatures_c=temps))


def _make_progress(opts: RunOptions, config: Config, plan: Plan, durations: list[float], phases: list[str]):
    """The live progress line (terminal only, unless asked for)."""
    import sys

    from payload_agent.output.progress import Progress

    stream = opts.progress_stream or sys.stdout
    enabled = opts.progress if opts.progress is not None else (stream.isatty() and not opts.unattended)
    if not enabled:
        return None
    scale = config.simulation.time_scale if config.simulation is not None else 1.0
    return Progress(stream, plan, durations, enabled=True, phases=phases, time_scale=scale)


def _check_empty_run(config: Config, plan: Plan, recorder: RunRecorder, phase_runner: PhaseRunner, retries: int,
                     out) -> None:
    """Segment the empty run right after it is recorded, before the operator mounts the tool. A sweep
    without a verified constant-speed window is redone now (within ``--retry-sweeps``), not found after
    the loaded run; past the budget the session stops here, before any loaded motion."""
    every = {m.sweep.name for m in plan.moves if m.sweep is not None}
    for attempt in range(retries + 1):
        _, failed = segment_phase(recorder.run_dir, "empty")
        if not failed:
            return
        problems = "\n  - ".join(failed.values())
        recorder.set_aside("empty", failed)  # not complete: `run --resume` records them again
        if attempt == retries:
            raise DataError(f"the empty-flange run cannot be segmented, so no loaded run was started:\n  - {problems}"
                            f"\nData kept in {recorder.run_dir}. Pass --retry-sweeps N to redo such sweeps at once, "
                            "or look at the sweeps in the report")
        out(f"  [empty] {', '.join(sorted(failed))} cannot be segmented; redoing before the tool is mounted "
            f"({retries - attempt - 1} retries left):\n  - {problems}")
        phase_runner.run_phase("empty", remaining_plan(config, plan, every - set(failed)), resume=True)


def _prepare_tool(phase: str, mounted: bool, cell, opts: RunOptions, out, changing: bool) -> None:
    if cell is not None:
        cell.mount_tool(mounted)
        out(f"Simulated tool change: tool {'mounted' if mounted else 'removed'}")
        return
    if not changing:
        return  # a loaded run from a stored baseline: the tool is on, as the operator asked for a run
    if opts.unattended:
        if opts.mode == "baseline":
            return  # `baseline --unattended`: the cell controller has emptied the flange
        raise RobotNotReadyError(f"the {phase} run needs the tool {'mounted' if mounted else 'removed'}, "
                                 "which an unattended run cannot ask for")
    what = "Mount the tool" if mounted else "Remove the tool (empty flange)"
    opts.ask(f"{what}, keep clear of the robot, then press Enter to continue. ")
