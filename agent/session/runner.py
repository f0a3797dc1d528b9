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

import math
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Callable

import numpy as np

from payload_agent import __version__
from payload_agent.session import baseline as baselines
from payload_agent.configuration.config import Config, config_snapshot
from payload_agent.drivers.base import Driver, PayloadSetting
from payload_agent.drivers.registry import driver_class
from payload_agent.errors import (BaselineError, CommunicationError, MotionAbortedError, PayloadAgentError,
                                  QualityGateError, RobotNotReadyError)
from payload_agent.motion.planner import Plan, expected_durations, make_plan
from payload_agent.recording.recorder import RunRecorder
from payload_agent.solvers.results import RunResult, format_table
from payload_agent.motion.safety import SafetyGate
from payload_agent.recording.state import RobotState

SAMPLE_WAIT_S = 5.0
SETTLED_RAD = math.radians(0.05)
READBACK_TOL_KG = 0.001  # the controllers store mass to 1 g or better
READBACK_TOL_M = 0.0005  # and the centre of mass to 0.5 mm or better
MODES = ("identify", "baseline", "calibrate")
NOT_REMOTE_MODES = ("local", "teach", "play")  # ControllerState.mode values in which motion commands are refused


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


@dataclass
class RunOutcome:
    run_dir: Path
    result: RunResult | None
    truth: dict | None = None
    timings: dict[str, float] = field(default_factory=dict)
    applied: PayloadSetting | None = None
    history_id: int | None = None
    report_path: Path | None = None
    calibration: Any = None


def make_driver(config: Config, options: dict | None = None) -> Driver:
    cls = driver_class(config.driver_type)
    return cls(options if options is not None else config.driver,
               max_joint_speed_rad_s=config.robot.max_joint_speed_rad_s)


def read_current_q(config: Config) -> np.ndarray:
    """Connect only to read where the robot stands now (for `plan --connect`); nothing moves."""
    cell = None
    options = dict(config.driver)
    if config.simulation is not None:
        from payload_agent.session.simulation import SimulatedCell

        cell = SimulatedCell(config).start()
        options = cell.options
    driver = make_driver(config, options)
    latest: list = []
    try:
        driver.connect()
        driver.start_stream(latest.append)
        deadline = time.monotonic() + SAMPLE_WAIT_S
        while not latest:
            if driver.stream_error is not None:
                raise CommunicationError(f"sample stream ended: {driver.stream_error}")
            if time.monotonic() > deadline:
                raise CommunicationError(f"no joint sample from the controller for {SAMPLE_WAIT_S:.0f} s")
            time.sleep(0.005)
        driver.stop_stream()
        return np.asarray(latest[-1].q, float)
    finally:
        driver.close()
        if cell is not None:
            cell.close()


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

    def __init__(self, config: Config, driver: Driver, gate: SafetyGate, recorder: RunRecorder, out,
                 progress=None):
        self.config, self.driver, self.gate, self.recorder, self.out = config, driver, gate, recorder, out
        self.progress = progress

    def sink(self, sample) -> None:
        self.recorder.sink(sample)
        if self.progress is not None:
            self.progress.on_sample(sample)

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
        self.recorder.begin_phase(name, joint_temperatures_c={"start": _temperatures(self.driver)})
        if self.progress is not None:
            self.progress.begin_phase(name)
        n = len(plan.moves)
        try:
            for i, move in enumerate(plan.moves, 1):
                q_now = self.current_q()
                if move.sweep is not None:
                    self.recorder.begin_sweep(move)
                self.out(f"  [{name}] {i}/{n} {move.label}")
                if self.progress is not None:
                    self.progress.begin_move(i, move, q_now)
                self.gate.execute(self.driver, move, q_now)
                done = time.monotonic()
                self.current_q(after=done, near=move.target_rad)  # the stream has caught up with the move
                if self.progress is not None:
                    self.progress.end_move()
                if move.sweep is not None:
                    self.recorder.end_sweep("complete")
        except BaseException as exc:
            self.stop_robot()
            if self.progress is not None:
                self.progress.close()
            self.recorder.end_sweep("aborted")
            self.recorder.end_phase(f"aborted: {type(exc).__name__}: {exc}")
            if isinstance(exc, KeyboardInterrupt):
                raise MotionAbortedError("interrupted by the operator (Ctrl-C); the robot was stopped, "
                                         f"recorded data kept in {self.recorder.run_dir}") from None
            raise
        self.recorder.manifest["phases"][name]["joint_temperatures_c"]["end"] = _temperatures(self.driver)
        self.recorder.end_phase("complete")

    def stop_robot(self) -> None:
        try:
            self.driver.stop()
        except Exception:
            pass


def _temperatures(driver: Driver) -> list[float] | None:
    """Joint temperatures, °C, where the controller reports them (friction depends on them)."""
    try:
        temps = driver.joint_temperatures_c()
    except PayloadAgentError:
        return None
    return None if temps is None else [round(float(t), 2) for t in temps]


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
    if opts.mode not in MODES:
        raise ValueError(f"unknown mode {opts.mode!r}")
    if opts.mode == "calibrate" and opts.reference is None:
        raise PayloadAgentError("calibrate needs the reference payload (--known-mass, --known-cog)")
    out = opts.out
    plan = make_plan(config)
    gate = SafetyGate(config)
    state = RobotState.for_config(config)
    own_cell = opts.cell is None and config.simulation is not None
    cell = opts.cell
    driver_options = dict(config.driver)
    if own_cell:
        from payload_agent.session.simulation import SimulatedCell

        cell = SimulatedCell(config).start()
    if cell is not None:
        driver_options = cell.options
        if opts.on_cell is not None:
            opts.on_cell(cell)
        out(f"Simulated {config.simulation.arm if config.simulation else ''} controller on "
            f"{driver_options.get('host')}; payload truth {cell.truth_json}")
    t0 = time.monotonic()
    driver = make_driver(config, driver_options)
    recorder = None
    outcome: RunOutcome | None = None
    try:
        driver.connect()
        info = driver.identify()
        ctl_state = driver.state()
        out(f"Connected: {info.vendor} {info.model}, firmware {info.firmware}; mode {ctl_state.mode}")
        if ctl_state.fault:
            raise RobotNotReadyError(f"the robot is not ready: {ctl_state.fault}. Clear it on the pendant and retry.")
        if ctl_state.mode in NOT_REMOTE_MODES:  # refuse before the plan is shown, not at the first move
            raise RobotNotReadyError(f"the controller is in {ctl_state.mode} mode: an external program cannot move "
                                     "the robot. Switch it to remote control on the teach pendant and retry.")
        if opts.mode == "identify":
            from payload_agent.evaluation.calibration import effective_gains

            note = effective_gains(config)[1]  # also refuses a calibration that no longer fits, before moving
            out(f"Drive gains: {note}" if note else "Drive gains: nominal (effort.gains_nm_per_unit); "
                "`payload-agent calibrate` with a known reference payload removes their error")
        current = baselines.describe_for(config, plan, info, source_run=Path("."),
                                         joint_temperatures_c=_temperatures(driver))
        phases, stored_info, store_empty = _phases_for(config, opts, state, current, out)
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        suffix = {"identify": "", "baseline": "-baseline", "calibrate": "-calibration"}[opts.mode]
        run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}{suffix}"
        n = 1
        while run_dir.exists():
            n += 1
            run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}{suffix}-{n}"
        recorder = RunRecorder(run_dir, {
            "format": "payload-agent-run/1", "software_version": __version__, "robot": config.robot.name,
            "mode": opts.mode, "tool": opts.tool,
            "config_source": config.source, "config": config_snapshot(config),
            "controller": baselines.controller_identity(info),
            "effort_unit": driver.effort_unit, "gains_nm_per_unit": list(config.effort.gains_nm_per_unit),
            "procedure": plan.procedure.name, "plan_fingerprint": plan.fingerprint(),
            "plan": [m.to_json() for m in plan.moves],
            "baseline": None if stored_info is None else {"dir": str(state.baseline_dir), **stored_info.to_json()},
            "reference_payload": None if opts.reference is None else {
                "mass_kg": opts.reference.mass_kg, "cog_mm": [1000 * c for c in opts.reference.cog_m]},
            "simulation_truth": cell.truth_json if cell else None,
        })
        if stored_info is not None:  # the run folder keeps its own copy: it stays self-contained
            recorder.manifest["phases"]["empty"] = baselines.copy_into_run(state, stored_info, recorder.run_dir)
            recorder.write_manifest()
        session = _Session(config, driver, gate, recorder, out)
        driver.start_stream(session.sink)
        start_q = session.current_q()
        verdict = gate.check(plan, start_q)
        durations = expected_durations(plan, start_q)
        out(describe_plan(plan, durations))
        session.progress = _make_progress(opts, config, plan, durations, [p for p, _ in phases])
        out("Safety gate: " + verdict.describe())
        if not verdict.ok:
            gate.approve(plan, start_q)  # raises SafetyError with every problem listed
        if not (opts.unattended or opts.assume_yes):
            what = " and ".join({"empty": "the empty-flange run", "loaded": "the loaded run"}[p] for p, _ in phases)
            answer = opts.ask(f"Record {what} now? The robot will move. [y/N] ")
            if answer.strip().lower() not in ("y", "yes"):
                raise MotionAbortedError("the operator declined; nothing moved")
        for phase, mounted in phases:
            _prepare_tool(phase, mounted, cell, opts, out, changing=len(phases) > 1 or opts.mode == "baseline")
            session.run_phase(phase, plan)
        if session.progress is not None:
            session.progress.close()
        t_motion = time.monotonic() - t0
        if store_empty:
            temps = recorder.manifest["phases"]["empty"].get("joint_temperatures_c", {}).get("end")
            stored = baselines.store_baseline(state, recorder.run_dir,
                                              baselines.describe_for(config, plan, info, recorder.run_dir,
                                                                     joint_temperatures_c=temps))
            out(f"Empty-flange baseline stored in {stored}")
        if opts.mode == "baseline":
            driver.stop_stream()
            recorder.update(finished_utc=datetime.now().astimezone().isoformat(timespec="seconds"))
            return RunOutcome(recorder.run_dir, None, cell.truth_json if cell else None,
                              {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion})
        driver.stop_stream()
        if driver.stream_error is not None:
            raise CommunicationError(f"the sample stream failed: {driver.stream_error}")
        outcome = _finish(config, opts, state, driver, recorder.run_dir, stored_info, cell)
        outcome.timings = {"wall_s": time.monotonic() - t0, "motion_wall_s": t_motion}
        recorder.update(finished_utc=datetime.now().astimezone().isoformat(timespec="seconds"))
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
            if own_cell and cell is not None:
                cell.close()
    if outcome.result is not None:
        from payload_agent.evaluation.quality import require_passed

        try:
            require_passed(outcome.result)
        except QualityGateError as exc:
            raise QualityGateError(f"{exc}\nData, result and report kept in {outcome.run_dir}") from None
    return outcome


def _finish(config: Config, opts: RunOptions, state: RobotState, driver: Driver, run_dir: Path,
            stored: baselines.BaselineInfo | None, cell) -> RunOutcome:
    """Analysis, calibration, history, report and write-back, while the controller is still connected."""
    out = opts.out
    truth = cell.truth_json if cell else None
    calibration = None
    if opts.mode == "calibrate":
        from payload_agent.evaluation.calibration import fit_gains, save_calibration

        ref = opts.reference
        calibration = fit_gains(config, run_dir, ref.mass_kg, ref.cog_m)
        path = save_calibration(state.ensure(), calibration)
        out("Drive-gain calibration (fitted / nominal): " + ", ".join(
            f"J{j + 1} {calibration.scale[j]:.4f} ± {1.96 * calibration.scale_std[j]:.4f}"
            for j in calibration.fitted_joints) + f"; stored in {path}")
    result = analyse(config, run_dir, solver=opts.solver)
    if opts.result_path is not None:
        result.write(opts.result_path)
    out(format_table(result, truth))
    out(f"Result written to {Path(run_dir) / 'result.json'}")
    outcome = RunOutcome(Path(run_dir), result, truth, calibration=calibration)
    outcome.history_id = _record_history(config, opts, state, result, stored, out)
    passed = bool(result.quality.get("passed", False))
    if opts.apply and opts.mode == "identify" and passed:
        outcome.applied = _apply(driver, result, opts, out)
        if outcome.history_id is not None:
            from payload_agent.output import history

            history.mark_applied(state.history_db, outcome.history_id, outcome.applied)
    elif opts.apply and not passed:
        out("Not applied: the quality checks failed (see above).")
    if opts.report:
        outcome.report_path = _write_report(config, run_dir, state, out)
    return outcome


def _record_history(config: Config, opts: RunOptions, state: RobotState, result: RunResult,
                    stored: baselines.BaselineInfo | None, out) -> int | None:
    if opts.mode == "calibrate":
        return None  # a reference payload, not a tool: kept out of the tool history
    from payload_agent.output import history

    entry = history.HistoryEntry.from_result_json(
        result.to_json(), tool=opts.tool,
        baseline_run_dir=None if stored is None else stored.source_run,
        baseline_fingerprint=None if stored is None else stored.plan_fingerprint,
        gains_note=result.extra.get("gains_source"),
        config_fingerprint=config.fingerprint("robot", "effort", "procedure"))
    entry_id = history.record(state.ensure().history_db, entry)
    flag = history.flag_for(state.history_db, entry_id)
    if flag is not None:
        out(f"Note: this result changed by more than its uncertainty since the last one: {flag.describe()}")
    return entry_id


def _write_report(config: Config, run_dir: Path, state: RobotState, out) -> Path | None:
    from payload_agent.output.report import write_report

    try:
        path = write_report(Path(run_dir), config, history_db=state.history_db)
    except Exception as exc:  # a report must never cost the result
        out(f"Report not written ({type(exc).__name__}: {exc}); the result is unaffected.")
        return None
    out(f"Report: {path}")
    return path


def _apply(driver: Driver, result: RunResult, opts: RunOptions, out) -> PayloadSetting:
    """Show the controller's current setting and the difference, write, read back, verify."""
    est = result.primary
    new = PayloadSetting(mass_kg=float(est.mass_kg), cog_m=tuple(float(c) for c in est.cog_m))
    try:
        current = driver.read_payload()
    except PayloadAgentError as exc:
        current = None
        out(f"Current controller payload setting: unknown ({exc})")
    if current is not None:
        out(describe_payload_change(current, new))
    if not (opts.unattended or opts.assume_yes):
        answer = opts.ask("Write the identified payload to the controller? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            out("Not applied (declined).")
            raise MotionAbortedError("the operator declined writing the payload; the result is kept")
    if current is not None and current.tool_num is not None:
        new = PayloadSetting(new.mass_kg, new.cog_m, current.tool_num)
    driver.write_payload(new)
    back = driver.read_payload()
    dm = abs(back.mass_kg - new.mass_kg)
    dc = max(abs(a - b) for a, b in zip(back.cog_m, new.cog_m))
    if dm > READBACK_TOL_KG or dc > READBACK_TOL_M:
        raise CommunicationError(
            f"the controller reads back {back.mass_kg:.4f} kg at {[round(1000 * c, 2) for c in back.cog_m]} mm "
            f"after writing {new.mass_kg:.4f} kg at {[round(1000 * c, 2) for c in new.cog_m]} mm")
    out(f"Applied and read back: {back.mass_kg:.4f} kg, centre of mass "
        f"{', '.join(f'{1000 * c:.1f}' for c in back.cog_m)} mm")
    return back


def describe_payload_change(current: PayloadSetting, new: PayloadSetting) -> str:
    cur_mm = [1000 * c for c in current.cog_m]
    new_mm = [1000 * c for c in new.cog_m]
    tool = f" (tool {current.tool_num})" if current.tool_num is not None else ""
    return (f"Controller payload setting{tool}: {current.mass_kg:.3f} kg at "
            f"[{', '.join(f'{v:.1f}' for v in cur_mm)}] mm\n"
            f"Identified:                 {new.mass_kg:.3f} kg at [{', '.join(f'{v:.1f}' for v in new_mm)}] mm\n"
            f"Difference:                 {new.mass_kg - current.mass_kg:+.3f} kg, "
            f"[{', '.join(f'{b - a:+.1f}' for a, b in zip(cur_mm, new_mm))}] mm")


def _make_progress(opts: RunOptions, config: Config, plan: Plan, durations: list[float], phases: list[str]):
    """The live progress line (terminal only, unless asked for)."""
    import sys

    from payload_agent.output.progress import Progress

    enabled = opts.progress if opts.progress is not None else (sys.stdout.isatty() and not opts.unattended)
    if not enabled:
        return None
    scale = config.simulation.time_scale if config.simulation is not None else 1.0
    return Progress(sys.stdout, plan, durations, enabled=True, phases=phases, time_scale=scale)


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


def analyse(config: Config, run_dir: Path, solver: str | None = None, baseline_dir: Path | None = None) -> RunResult:
    """Analyse a run folder (gains: the robot's valid calibration, else nominal) and write result.json."""
    from payload_agent.evaluation.pipeline import analyse_run

    result = analyse_run(config, run_dir, solver, baseline_dir)
    result.write(Path(run_dir) / "result.json")
    return result
