"""The end of a session: analysis, calibration, history, write-back and report, while still connected.

Every result is written into the run folder before anything is written to the controller, and
the controller is written to only when the quality checks passed and the operator asked for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver
from payload_agent.output.pendant import payload_write_record
from payload_agent.recording.state import RobotState
from payload_agent.session.apply import apply_result, payload_to_write
from payload_agent.session.baseline import BaselineInfo
from payload_agent.session.modes import Mode
from payload_agent.session.options import OperatorUI, RunOptions
from payload_agent.solvers.results import RunResult, format_table
from payload_agent.types import PayloadSetting


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


def finish(config: Config, mode: Mode, opts: RunOptions, ui: OperatorUI, state: RobotState, driver: Driver,
           run_dir: Path, stored: BaselineInfo | None, cell) -> RunOutcome:
    """Analysis, calibration, history, report and write-back, while the controller is still connected."""
    out = ui.out
    truth = cell.truth_json if cell else None
    calibration = mode.before_analysis(config, opts, state, run_dir, out)
    result = analyse(config, run_dir, solver=opts.solver)
    if opts.result_path is not None:
        result.write(opts.result_path)
    out(format_table(result, truth))
    out(f"Result written to {Path(run_dir) / 'result.json'}")
    outcome = RunOutcome(Path(run_dir), result, truth, calibration=calibration)
    outcome.history_id = _record_history(config, opts, state, result, stored, out) if mode.keeps_results else None
    passed = bool(result.quality.get("passed", False))
    if opts.tool and mode.keeps_results and passed:  # the tool library keeps tools that passed only
        from payload_agent.tools.library import store_result, tool_library_path

        entry = store_result(tool_library_path(state.ensure().root), config.robot.name, opts.tool,
                             result.to_json(), outcome.history_id)
        out(f"Tool library: stored {entry.describe()}")
    if opts.apply and mode.may_apply and passed:
        written, why_no_inertia = payload_to_write(result, driver)
        outcome.applied = apply_result(driver, result, ui.ask if opts.asks else None, out)
        _record_write(run_dir, payload_write_record(True, True, written, outcome.applied, note=why_no_inertia))
        if outcome.history_id is not None:
            from payload_agent.recording import history

            history.mark_applied(state.history_db, outcome.history_id, outcome.applied)
    elif opts.apply and not passed:
        out("Not applied: the quality checks failed (see above).")
        _record_write(run_dir, payload_write_record(True, False, reason="the quality checks failed"))
    if opts.report:
        outcome.report_path = write_run_report(config, run_dir, state, out)
    return outcome


def _record_history(config: Config, opts: RunOptions, state: RobotState, result: RunResult,
                    stored: BaselineInfo | None, out) -> int | None:
    from payload_agent.recording import history

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


def write_run_report(config: Config, run_dir: Path, state: RobotState | None, out) -> Path | None:
    from payload_agent.output.report import write_report

    try:
        path = write_report(Path(run_dir), config, history_db=None if state is None else state.history_db)
    except Exception as exc:  # a report must never cost the result
        out(f"Report not written ({type(exc).__name__}: {exc}); the result is unaffected.")
        return None
    out(f"Report: {path}")
    return path


def analyse(config: Config, run_dir: Path, solver: str | None = None, baseline_dir: Path | None = None) -> RunResult:
    """Analyse a run folder (gains: the robot's valid calibration, else nominal) and write result.json."""
    from payload_agent.evaluation.pipeline import analyse_run

    result = analyse_run(config, run_dir, solver, baseline_dir)
    result.write(Path(run_dir) / "result.json")
    return result


def _record_write(run_dir: Path, record: dict[str, Any]) -> None:
    """The manifest's ``payload_write``: what was asked, written and read back (or why not)."""
    from payload_agent.recording.recorder import RunRecorder

    RunRecorder.reopen(run_dir).update(payload_write=record)
