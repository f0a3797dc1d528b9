"""One session with the robot: connect, check, move through the approved plan, record, analyse, apply.

``Session`` is the skeleton every kind of session shares; what differs between them (which phases are
recorded, what happens with the recording) is its mode's (``modes.py``: identify, baseline, calibrate,
resume). The connected readiness checks are ``readiness.py``'s, stopping at the first failure.

Motion only ever goes through the SafetyGate. Any exception, Ctrl-C or lost
connection stops the robot; what was recorded stays in the run folder. Nothing is
written to the controller unless the quality gates passed and the operator asked for it.
"""

from __future__ import annotations

import shutil
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver
from payload_agent.errors import (CommunicationError, DataError, MotionAbortedError, PayloadAgentError,
                                  QualityGateError, SafetyError)
from payload_agent.motion.planner import Plan, expected_durations, parked, remaining_plan, turned_to
from payload_agent.motion.safety import SafetyGate
from payload_agent.analysis.run_deltas import segment_phase
from payload_agent.evaluation.calibration import RUN_CALIBRATION, effective_calibration
from payload_agent.recording import resting_pose
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.state import RobotState
from payload_agent.session import baseline as baselines
from payload_agent.session import run_ends
from payload_agent.output.console import attach_run_log, detach_run_log
from payload_agent.output.plan_table import format_plan
from payload_agent.session.finish import RunOutcome, finish, write_run_report
from payload_agent.session.robot_lock import robot_lock
from payload_agent.session.connection import SAMPLE_WAIT_S, build_driver, simulated_cell
from payload_agent.session.manifest import RunManifest, new_run_dir
from payload_agent.session.modes import Mode, Resume, Selection, mode_for
from payload_agent.session.options import OperatorUI, RunOptions, SimulatedCellUse
from payload_agent.output.stop_text import stop_sentence
from payload_agent.session.phases import PhaseRunner, joint_temperatures
from payload_agent.session.preflight import preflight
from payload_agent.session.readiness import Probe, first_failure
from payload_agent.session.resume import config_fingerprint, load_resume

__all__ = ["RunOptions", "OperatorUI", "SimulatedCellUse", "RunOutcome", "Session", "run_identification"]


def run_identification(config: Config, opts: RunOptions = RunOptions(), ui: OperatorUI = OperatorUI(),
                       sim: SimulatedCellUse = SimulatedCellUse()) -> RunOutcome:
    """One session of ``opts.mode`` (see ``Session``)."""
    return Session(config, opts, ui, sim).run()


class Session:
    """Connect, check, show the plan, move through it, record, then the mode's finish; every exit stops the
    robot (only motion this session commanded) and keeps what was recorded."""

    def __init__(self, config: Config, opts: RunOptions, ui: OperatorUI = OperatorUI(),
                 sim: SimulatedCellUse = SimulatedCellUse()):
        self.config, self.opts, self.ui, self.sim = config, opts, ui, sim
        self.mode: Mode = mode_for(opts)
        self.state = RobotState.for_config(config)

    def run(self) -> RunOutcome:
        config, opts, ui = self.config, self.opts, self.ui
        # everything `plan` checks, once, before anything starts: the YAML, the plan and the safety gate's view of
        # it, the driver section and what the options need of it, the stored calibration
        plan = preflight(config, calibration=self.mode.uses_calibration,
                         apply=opts.apply and self.mode.may_apply).require().plan
        if opts.resume is not None:
            self.mode = Resume(load_resume(config, plan, opts.resume))
        with robot_lock(self.state, self.mode.command, config.robot.name, ui.out), \
                simulated_cell(config, self.sim.cell) as cell:  # one session per robot, before connecting
            driver = build_driver(config, cell.options if cell else None)
            if cell is not None:
                if self.sim.on_cell is not None:
                    self.sim.on_cell(cell)
                ui.out(f"Simulated {config.simulation.arm if config.simulation else ''} controller at "
                       f"{driver.describe_endpoint()}; payload truth {cell.truth_json}")
            return self._connected(plan, cell, driver)

    def _connected(self, plan: Plan, cell, driver: Driver) -> RunOutcome:
        config, opts, ui, mode, state = self.config, self.opts, self.ui, self.mode, self.state
        out = ui.out
        t0 = time.monotonic()
        recorder = log = None
        try:
            driver.connect()
            probe = _check_controller(config, mode, ui, driver, plan)
            plan = turned_to(config, plan, probe.q)  # a joint at ±180° is reached the short way from here
            current = baselines.describe_for(config, plan, probe.info, source_run=Path("."),
                                             joint_temperatures_c=joint_temperatures(driver))
            chosen = mode.select(config, plan, opts, state, current, probe.info, out)
            if opts.return_to_start:
                chosen = run_ends.returning(config, chosen, probe.q)
            if opts.park:
                chosen = run_ends.parking(config, chosen, out)
            resting = resting_pose.standing_at(state.root, probe.q)
            gate = SafetyGate(config, resting)  # the gate compares the record with the angles itself
            if resting is not None:
                chosen = run_ends.from_rest(config, chosen)
                out(f"The arm rests at {resting.describe()}: the first move runs at travel speed")
            durations = _show_and_confirm(config, opts, ui, driver, gate, chosen, probe.q)
            changing = len(chosen.todo) > 1 or mode.empties_flange
            first, mounted, _ = chosen.todo[0]
            _prepare_tool(first, mounted, cell, mode, opts, ui, changing)  # asked before any folder exists
            recorder = _open_recorder(config, mode, opts, plan, probe, driver, state, cell, chosen)
            log = attach_run_log(recorder.run_dir)
            out(f"Run folder: {recorder.run_dir}")
            phase_runner = PhaseRunner(config, driver, gate, recorder, ui.say_detail,
                                       _make_progress(ui, opts, config, plan, durations, [p for p, _ in chosen.phases]),
                                       retry_sweeps=opts.retry_sweeps)
            driver.start_stream(phase_runner.sink)
            for i, (phase, mounted, phase_plan) in enumerate(chosen.todo):
                if i > 0:
                    _prepare_tool(phase, mounted, cell, mode, opts, ui, changing)
                phase_runner.run_phase(phase, phase_plan, resume=mode.resumed)
                if phase in ("empty", "loaded"):  # checked while the robot and the tool are as recorded
                    whole = parked(config, plan) if opts.park and i == len(chosen.todo) - 1 else plan
                    _check_segmentation(config, phase, whole, recorder, phase_runner, opts.retry_sweeps, out)
            if phase_runner.progress is not None:
                phase_runner.progress.close()
            driver.stop_stream()
            t_motion = time.monotonic() - t0
            if driver.stream_error is not None:
                raise CommunicationError(f"the sample stream failed: {driver.stream_error}")
            if chosen.store_empty:
                stored = _store_baseline(config, plan, probe.info, state, recorder)
                out(f"Empty-flange baseline stored in {stored}")
            if not mode.analyses:
                recorder.mark_complete()
                return RunOutcome(recorder.run_dir, None, cell.truth_json if cell else None,
                                  {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion})
            outcome = finish(config, mode, opts, ui, state, driver, recorder.run_dir, chosen.stored, cell)
            outcome.timings = {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion}
            recorder.mark_complete()
        except BaseException as exc:
            stop_sent = driver.stop()  # only motion this session commanded; a refusal before our first move sends nothing
            if recorder is not None:
                _mark_stopped(config, recorder, exc, opts, out, stop_sent)
            raise
        finally:
            try:
                driver.close()
            finally:  # a second Ctrl-C while closing must not leave this run's log attached to the next
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


def _check_controller(config: Config, mode: Mode, ui: OperatorUI, driver: Driver, plan: Plan) -> Probe:
    """The readiness checks (identity, state, drive gains, kinematic cross-check), stopping at the first
    failure, before anything is shown or moved; each says what it found."""
    probe = Probe(config, driver, plan)
    names = ("identify", "state", "calibration", "pose") if mode.uses_calibration else ("identify", "state", "pose")
    first_failure(probe, names, seen=lambda check: _say_check(ui.out, probe, check))
    if probe.q is None:
        probe.q = np.asarray(driver.wait_sample(SAMPLE_WAIT_S).q, float)
    return probe


def _streams_target_signals(driver: Driver) -> bool:
    """Whether the samples carry the controller's target current and torque (the gains can come from them)."""
    try:
        return driver.wait_sample(SAMPLE_WAIT_S).target_current is not None
    except PayloadAgentError:
        return False


def _say_check(out, probe: Probe, check) -> None:
    if check.name == "state":
        detail = check.data.get("detail")
        out(f"Connected: {probe.info.vendor} {probe.info.model}, firmware {probe.info.firmware}"
            + (f" ({detail})" if detail else ""))
    elif check.name == "drive-gain calibration" and check.error is None:
        note = probe.gains_note
        if note is None and _streams_target_signals(probe.driver):  # UR: evaluation.controller_gains after the run
            note = ("the controller's own constants, fitted from its target_current / target_moment after the run "
                    "(nominal effort.gains_nm_per_unit where they do not determine a joint)")
        out(f"Drive gains: {note}" if note else "Drive gains: nominal "
            "(effort.gains_nm_per_unit); `payload-agent calibrate` with a known reference payload removes "
            "their error")
    elif check.name == "kinematic cross-check" and probe.pose is not None and check.error is None:
        out(f"Kinematic cross-check: YAML model and controller agree within "
            f"{1000 * probe.pose.position_error_m:.1f} mm, {np.degrees(probe.pose.rotation_error_rad):.2f}°")


def _show_and_confirm(config: Config, opts: RunOptions, ui: OperatorUI, driver: Driver, gate: SafetyGate,
                      chosen: Selection, start_q: np.ndarray) -> list[float]:
    """Show the plan and the gate's verdict; refuse a failing plan, or a later run that cannot start where the
    one before it ends; ask before the robot moves."""
    plan, phases = chosen.todo[0][2], chosen.phases
    verdict = gate.check(plan, start_q)
    durations = expected_durations(plan, start_q)
    ui.out(format_plan(plan, durations))
    ui.out("Safety gate: " + verdict.describe())
    if not verdict.ok:
        gate.approve(plan, start_q)  # raises SafetyError with every problem listed
    _refuse_unreachable_runs(gate, chosen, start_q, ui.out)
    _confirm_without_pose_check(config, driver, plan, opts, ui)
    if opts.asks:
        what = " and ".join({"empty": "the empty-flange run", "loaded": "the loaded run"}[p] for p, _ in phases)
        answer = ui.ask(f"Record {what} now? The robot will move. [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            raise MotionAbortedError("the operator declined; nothing moved")
    return durations


def _refuse_unreachable_runs(gate: SafetyGate, chosen: Selection, start_q: np.ndarray, out) -> None:
    """Each later run of the session (the loaded run after the empty run) starts where the one before it ends:
    the gate checks it from there now, before the first move, and a failure refuses the whole session (the
    standards: the plan is validated whole before the first move; found after the empty run, it would be refused
    only once that run had moved)."""
    names = {"empty": "the empty-flange run", "loaded": "the loaded run"}
    q = start_q
    for (before, _, first), (phase, _, then) in zip(chosen.todo, chosen.todo[1:]):
        verdict = gate.check_after(then, first, q)
        q = first.moves[-1].target_rad if first.moves else q
        if verdict.ok:
            out(f"Safety gate, {names[phase]} from where {names[before]} ends: SAFE")
            continue
        end = ", ".join(f"{np.degrees(v):.1f}" for v in q)
        begin = ", ".join(f"{np.degrees(v):.1f}" for v in then.moves[0].target_rad)
        raise SafetyError(
            f"the safety gate refused the session before its first move: {names[phase]} starts where "
            f"{names[before]} ends ([{end}] deg) and its first target is [{begin}] deg:\n"
            + "\n".join(f"  - {p}" for p in verdict.problems)
            + ("\nThe move back to the plan's first pose (--park) is refused: `payload-agent plan --park` shows it; "
               "leave --park out, or choose a plan whose end lies within reach of its first pose."
               if any("(park at " in p for p in verdict.problems) else
               "\nThe plan does not close its loop (`payload-agent plan` says whether it does). Record the runs in "
               "two sessions (`payload-agent baseline` with the empty flange; move the arm to within 200° of that first "
               "target in every joint; then this command, which uses the stored baseline), or change the procedure "
               "so that it ends within reach of its start."))


def _open_recorder(config: Config, mode: Mode, opts: RunOptions, plan: Plan, probe: Probe, driver: Driver,
                   state: RobotState, cell, chosen: Selection) -> RunRecorder:
    """The run folder: a new one with its manifest, or the resumed one."""
    if isinstance(mode, Resume):
        recorder = RunRecorder.reopen(mode.resume.run_dir)
        recorder.mark_resumed()
        return recorder
    stored_info, pose_check = chosen.stored, probe.pose
    recorder = RunRecorder(new_run_dir(config, mode.name, datetime.now().strftime("%Y%m%d-%H%M%S")), {
        **RunManifest(config, plan, mode.name, baselines.controller_identity(probe.info), driver.effort_unit,
                      opts.tool, None if stored_info is None else {"dir": str(state.baseline_dir),
                                                                  **stored_info.to_json()},
                      opts.reference, cell.truth_json if cell else None,
                      None if pose_check is None else pose_check.to_json()).to_json(),
        "config_fingerprint": config_fingerprint(config), "phases_planned": chosen.phases,
        "store_empty": chosen.store_empty,
        # the session's first move as it runs: at travel speed from our own resting pose, the plan's approach else
        "first_move": chosen.todo[0][2].moves[0].to_json() if chosen.todo[0][2].moves else None,
        "solver": opts.solver or config.procedure.solver})  # `solve` redoes the run with the run's own solver
    if stored_info is not None:  # the run folder keeps its own copy: self-contained
        recorder.adopt_phase("empty", baselines.copy_into_run(state, stored_info, recorder.run_dir))
    if mode.analyses and effective_calibration(config) is not None:  # what its analysis will use, from
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


def _confirm_without_pose_check(config: Config, driver: Driver, plan: Plan, opts: RunOptions,
                                ui: OperatorUI) -> None:
    """A controller that reports no flange pose: the YAML kinematics cannot be cross-checked.

    Interactive runs show the planned flange heights and ask; unattended runs need the
    explicit acknowledgement ``safety.unattended_without_pose_check: true``.
    """
    if driver.reports_flange_pose:
        return
    heights = [1000 * float(config.robot.kinematics.flange(m.target_rad)[2, 3]) for m in plan.moves]
    ui.out(f"This controller reports no flange pose: the YAML kinematics cannot be checked against the robot. "
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
        answer = ui.ask("Do the planned flange heights match the robot's surroundings? [y/N] ")
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


def _make_progress(ui: OperatorUI, opts: RunOptions, config: Config, plan: Plan, durations: list[float],
                   phases: list[str]):
    """The live progress line (terminal only, unless asked for)."""
    import sys

    from payload_agent.output.progress import Progress

    stream = ui.progress_stream or sys.stdout
    enabled = ui.progress if ui.progress is not None else (stream.isatty() and not opts.unattended)
    if not enabled:
        return None
    scale = config.simulation.time_scale if config.simulation is not None else 1.0
    return Progress(stream, plan, durations, enabled=True, phases=phases, time_scale=scale)


def _check_segmentation(config: Config, phase: str, plan: Plan, recorder: RunRecorder, phase_runner: PhaseRunner,
                        retries: int, out) -> None:
    """Segment a phase right after it is recorded. A sweep without a verified constant-speed window (a stream
    that stalled for less than the watchdog's limit leaves a hole) is redone now, within ``--retry-sweeps``:
    the empty run's before the operator mounts the tool, the loaded run's while the tool is still on, not found
    by the analysis after the session. Past the budget the session stops here, the data kept. ``plan`` is the
    whole plan, not a resumed phase's rest: a sweep recorded by an earlier session can be the one redone."""
    recorded = {m.recorded_name for m in plan.moves if m.recorded_name is not None}
    for attempt in range(retries + 1):
        _, failed = segment_phase(recorder.run_dir, phase)
        if not failed:
            return
        problems = "\n  - ".join(failed.values())
        recorder.set_aside(phase, failed)  # not complete: `run --resume` records them again
        if attempt == retries:
            after = "so no loaded run was started" if phase == "empty" else "so it was not analysed"
            raise DataError(f"the {'empty-flange' if phase == 'empty' else 'loaded'} run cannot be segmented, "
                            f"{after}:\n  - {problems}\nData kept in {recorder.run_dir}. Pass --retry-sweeps N to "
                            "redo such sweeps at once, or look at the sweeps in the report")
        when = "before the tool is mounted" if phase == "empty" else "with the tool still on"
        out(f"  [{phase}] {', '.join(sorted(failed))} cannot be segmented; redoing {when} "
            f"({retries - attempt - 1} retries left):\n  - {problems}")
        phase_runner.run_phase(phase, remaining_plan(config, plan, recorded - set(failed)), resume=True)


def _prepare_tool(phase: str, mounted: bool, cell, mode: Mode, opts: RunOptions, ui: OperatorUI,
                  changing: bool) -> None:
    """The tool change a phase needs: done by the simulated cell, asked of the operator, or refused."""
    out = ui.out
    if cell is not None:
        cell.mount_tool(mounted)
        out(f"Simulated tool change: tool {'mounted' if mounted else 'removed'}")
        return
    if not changing:
        return  # a loaded run from a stored baseline: the tool is on, as the operator asked for a run
    if opts.unattended:
        mode.unattended_tool_change(phase, mounted)  # refuses, unless the mode's caller prepared the flange
        return
    what = "Mount the tool" if mounted else "Remove the tool (empty flange)"
    ui.ask(f"{what}, keep clear of the robot, then press Enter to continue. ")
