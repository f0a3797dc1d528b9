"""What each ``payload-agent`` command does (the parser and error handling are in ``payload_agent.cli``).

Every command gets the parsed arguments and a Console (``payload_agent.output.console``):
human text through ``con.say``/``con.result`` (stderr with --json), the one JSON document
through ``con.emit_json``. Commands return their exit code; errors are raised as
PayloadAgentError and turned into exit codes by ``cli.main``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Callable

from payload_agent.cli_import import cmd_import, load_robot
from payload_agent.configuration.config import Config
from payload_agent.errors import CommunicationError, ConfigError, QualityGateError
from payload_agent.output.console import Console
from payload_agent.tools.commands import TOOL_COMMANDS
from payload_agent.verify_command import VERIFY_COMMANDS
from payload_agent.plc.commands import SERVE_COMMANDS

NO_TERMINAL_HINT = {
    "identify": "Pass --yes to accept the plan without asking (tool changes are still asked for), or --unattended "
                "for a cell controller (never asks; needs a stored baseline that fits).",
    "baseline": "Pass --unattended when the flange is known to be empty (--yes still asks to remove the tool).",
    "calibrate": "Pass --yes to accept the plan, and --unattended if the reference payload is already mounted and "
                 "a stored baseline fits.",
}


# -- sessions that move the robot ---------------------------------------------------------------
def _run_options(args, mode: str, **extra):
    """What the command's flags ask of the session (session/options.py)."""
    from payload_agent.session.options import RunOptions

    return RunOptions(mode=mode, unattended=args.unattended, assume_yes=args.yes,
                      result_path=Path(args.result) if getattr(args, "result", None) else None,
                      solver=getattr(args, "solver", None), tool=getattr(args, "tool", None),
                      fresh_baseline=getattr(args, "fresh_baseline", False),
                      report=not getattr(args, "no_report", False), retry_sweeps=getattr(args, "retry_sweeps", 0) or 0,
                      resume=Path(args.resume) if getattr(args, "resume", None) else None, **extra)


def _operator_ui(con: Console, mode: str):
    """How the session talks to the person at the terminal (or to nobody, with --json's stdout kept clean)."""
    from payload_agent.session.options import OperatorUI

    return OperatorUI(out=con.say, ask=con.asker(NO_TERMINAL_HINT[mode]), detail=con.detail,
                      progress_stream=con.human)


def _session(args, con: Console, mode: str, on_cell=None, adjust=None, **extra):
    from payload_agent.recording.state import describe_locations
    from payload_agent.session.runner import SimulatedCellUse, run_identification

    config = load_robot(args) if adjust is None else adjust(load_robot(args))  # adjust: a command-line override
    con.say(describe_locations(config))
    try:  # checks everything `plan` checks before anything starts (session.preflight), once
        outcome = run_identification(config, _run_options(args, mode, **extra), _operator_ui(con, mode),
                                     SimulatedCellUse(on_cell=on_cell))
    except QualityGateError as exc:
        outcome = getattr(exc, "outcome", None)
        if outcome is not None:
            _summary(con, config, outcome)
        raise
    _summary(con, config, outcome)
    return config, outcome


def _summary(con: Console, config: Config, outcome) -> None:
    """The last lines of a run: where its folder is, and the values for the controller."""
    from payload_agent.output.checks import failed_summary
    from payload_agent.output.pendant import pendant_values

    if con.verbosity < 0:  # otherwise the session already said it, when it created the folder
        con.result(f"Run folder: {Path(outcome.run_dir).absolute()}")
    result = getattr(outcome, "result", None)
    if result is None:
        return
    est = result.primary
    passed = bool(result.quality.get("passed", False))
    pv = pendant_values(config.driver_type, est.mass_kg, est.cog_mm)
    if passed:
        con.result(pv.describe())
        applied = getattr(outcome, "applied", None)
        con.result("Written to the controller and read back." if applied is not None else
                   "Not written to the controller (type the values above, or run with --apply).")
    else:
        con.result("Quality checks FAILED: do not type these values into the controller.")
        for line in failed_summary(result.quality):
            con.result("  " + line)


def outcome_json(outcome) -> dict[str, Any]:
    from payload_agent.output.pendant import pendant_values

    result = getattr(outcome, "result", None)
    data: dict[str, Any] = {"run_dir": str(outcome.run_dir), "result": None if result is None else result.to_json(),
                            "applied": None, "history_id": getattr(outcome, "history_id", None),
                            "report": None if getattr(outcome, "report_path", None) is None else str(outcome.report_path),
                            "simulation_truth": getattr(outcome, "truth", None)}
    applied = getattr(outcome, "applied", None)
    if applied is not None:
        data["applied"] = {"mass_kg": applied.mass_kg, "cog_mm": [1000 * c for c in applied.cog_m],
                           "tool_num": applied.tool_num, "inertia_com_kgm2": applied.inertia_com_kgm2}
    if result is not None:
        cfg = None
        try:
            from payload_agent.recording.rundata import load_manifest
            from payload_agent.output.pendant import driver_type_of

            cfg = driver_type_of(load_manifest(Path(outcome.run_dir)))
        except Exception:
            pass
        data["controller_values"] = pendant_values(cfg, result.primary.mass_kg, result.primary.cog_mm).to_json()
        data["quality_passed"] = bool(result.quality.get("passed", False))
    return data


def cmd_run(args, con: Console) -> int:
    _, outcome = _session(args, con, "identify", apply=args.apply)
    con.emit_json({"ok": True, "exit_code": 0, **outcome_json(outcome)})
    return 0


def cmd_baseline(args, con: Console) -> int:
    _session(args, con, "baseline")
    return 0


def cmd_calibrate(args, con: Console) -> int:
    from payload_agent.calibrate_args import reference_payload, with_procedure, with_speed, with_sweep_and_motion

    ref, cog = reference_payload(args.known_mass, args.known_cog)

    def mount_reference(cell) -> None:  # a simulated robot: the reference named here is what gets mounted
        cell.change_tool(args.known_mass, cog)
        con.say(f"Simulated robot: the reference payload {args.known_mass:g} kg at [{args.known_cog}] mm is the "
                "simulated tool for this calibration (the YAML's simulation.payload is not used)")

    _session(args, con, "calibrate", reference=ref, on_cell=mount_reference, park=args.park,
             adjust=lambda config: with_sweep_and_motion(with_procedure(with_speed(config, args.speed_percent),
                                                                        args.procedure),
                                                         args.sweep_deg, args.travel_speed_percent, args.accel_percent))
    return 0


def cmd_watch(args, con: Console) -> int:
    from payload_agent.session.connection import build_driver
    from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification
    from payload_agent.session.watch import watch

    from payload_agent.session.preflight import preflight

    config = load_robot(args)
    preflight(config, watch=True).require()  # every run it starts applies: refuse now what could never succeed
    cell = None
    if config.simulation is not None:  # one simulated cell for the whole watch: its inputs can be set
        from payload_agent.session.simulation import SimulatedCell

        cell = SimulatedCell(config).start()

    def run_once() -> int:
        run_identification(config, RunOptions(unattended=True, apply=True, tool=args.tool),
                                   OperatorUI(out=con.say),
                                   SimulatedCellUse(cell=cell))
        return 0

    def run_tool(name: str | None) -> int:  # the trigger named the tool: verify a known one, identify a new one
        from payload_agent.session.tool_change import change_tool

        con.say(f"Tool change: {change_tool(config, name or args.tool, cell=cell, out=con.say).detail}")
        return 0

    try:
        return watch(config, run_once, max_runs=args.max_runs, run_tool=run_tool,
                     driver_factory=lambda: build_driver(config, cell.options if cell else None))
    finally:
        if cell is not None:
            cell.close()


# -- commands that never move -------------------------------------------------------------------
def cmd_plan(args, con: Console) -> int:
    import numpy as np

    from payload_agent.motion.planner import expected_durations, parked, turned_to
    from payload_agent.motion.safety import APPROACH_UNKNOWN, SafetyGate
    from payload_agent.output.plan_table import format_plan, plan_json
    from payload_agent.recording.state import RobotState, describe_locations
    from payload_agent.session.baseline import status_line
    from payload_agent.session.preflight import preflight

    config = load_robot(args)
    for option, value in (("--payload-kg", args.payload_kg), ("--payload-cog-mm", args.payload_cog_mm),
                          ("--tool", args.tool)):
        if value is not None and not getattr(args, "target_std", None):
            raise ConfigError(option, "is the payload --target-std predicts for; give --target-std G,MM too")
    pre = preflight(config)
    if args.from_deg and args.connect:
        raise ConfigError("--from-deg", "give either --from-deg or --connect, not both")
    start = None
    if pre.plan is not None and args.from_deg:
        try:
            start = np.radians([float(v) for v in args.from_deg.split(",")])
        except ValueError:
            raise ConfigError("--from-deg", f"expected six joint angles in degrees separated by commas, "
                              f"got {args.from_deg!r}") from None
        if start.shape != (6,):
            raise ConfigError("--from-deg", f"expected six joint angles, got {start.size}")
    elif pre.plan is not None and args.connect and pre.ok:
        start = read_current_q_named(config)
        con.say("Robot stands at [" + ", ".join(f"{v:.2f}" for v in np.degrees(start)) + "] deg")
    data: dict[str, Any] = {"robot": config.robot.name, "config": config.source, "preflight": pre.to_json()}
    verdict = None
    if pre.plan is not None:
        pre.plan = turned_to(config, pre.plan, start)  # as run will: a joint at ±180° reached the short way
        if args.park:  # as `calibrate --park` runs it
            pre.plan = parked(config, pre.plan)
        durations = expected_durations(pre.plan, start)
        con.say(format_plan(pre.plan, durations))
        baseline = status_line(RobotState.for_config(config), config, pre.plan)
        con.say(baseline)
        verdict = SafetyGate(config).check(pre.plan, start)
        con.say("Safety gate: " + verdict.describe())
        data.update(plan=plan_json(pre.plan, durations), baseline=baseline,
                    safety={"ok": verdict.ok, "problems": verdict.problems, "checks": verdict.checks,
                            "approach_checked": start is not None})
    if getattr(args, "target_std", None) and pre.ok:
        from payload_agent.session.target import plan_target

        data["target"] = plan_target(config, args, start, con)
    for note in pre.notes:
        con.say(note[0].upper() + note[1:])
    con.say(describe_locations(config))
    for p in pre.problems:
        con.error(f"payload-agent: error: {p}")
    approach_only = verdict is not None and all(p.startswith(APPROACH_UNKNOWN) for p in verdict.problems)
    ok = pre.ok and verdict is not None and (verdict.ok or (start is None and approach_only))
    if pre.ok and verdict is not None and not ok:
        con.error(f"payload-agent: error: {config.source}: the safety gate refused the plan:\n"
                  + "\n".join(f"  - {p}" for p in verdict.problems))
    code = 0 if ok else 2
    con.emit_json({"ok": ok, "exit_code": code, **data})
    return code


def read_current_q_named(config: Config):
    """``plan --connect``: where the robot stands; a failure names the driver, host and ports."""
    from payload_agent.session.connection import read_current_q
    from payload_agent.session.doctor import endpoint_text

    try:
        return read_current_q(config)
    except CommunicationError as exc:
        where = endpoint_text(config)
        text = str(exc)
        if where.split(" (")[0].split(" at ")[-1] in text and "port" in text:
            raise
        raise CommunicationError(f"{text} [{where}]") from None


def cmd_doctor(args, con: Console) -> int:
    from payload_agent.session.doctor import run_doctor

    config = load_robot(args)
    if not args.seconds > 0:
        raise ConfigError("--seconds", f"must be > 0, got {args.seconds:g}")
    report = run_doctor(config, stream_window_s=args.seconds, progress=con.detail)
    for line in report.describe().splitlines()[:-1]:
        con.say(line)
    con.result(report.verdict())
    con.emit_json({"ok": report.ready, **report.to_json()})
    return report.exit_code


def cmd_history(args, con: Console) -> int:
    from payload_agent.output.history_table import format_history
    from payload_agent.recording import history
    from payload_agent.recording.state import RobotState

    config = load_robot(args)
    db = RobotState.for_config(config).history_db
    all_entries = history.entries(db, tool=args.tool)
    flags = history.compare_to_previous(all_entries)
    shown = all_entries[-args.limit:] if args.limit else all_entries
    if not db.exists():
        con.say(f"No history yet for robot {config.robot.name!r} ({db}).")
    else:
        con.say(format_history(shown, flags))
        con.say(f"Run folders: {Path(config.storage.runs_dir).absolute()} (`solve` and `report` take a run "
                "folder's name)")
    ids = {e.id for e in shown}
    con.emit_json({"ok": True, "robot": config.robot.name, "database": str(db),
                   "runs_dir": str(Path(config.storage.runs_dir).absolute()),
                   "entries": [history.entry_json(e) for e in shown],
                   "change_flags": [dataclasses.asdict(f) | {"text": f.describe()} for f in flags if f.entry_id in ids]})
    return 0


def cmd_report(args, con: Console) -> int:
    from payload_agent.configuration.paths import state_home
    from payload_agent.output.report import write_report
    from payload_agent.recording.state import RobotState

    run_dir = _existing_run_dir(args.run_dir, "RUN_DIR", args)
    manifest, config = recorded_config(args, run_dir)
    db = (RobotState.for_config(config).history_db if args.robot
          else state_home() / str(manifest.get("robot", config.robot.name)) / "history.sqlite")
    path = write_report(run_dir, config, history_db=db if db.exists() else None, out_path=_report_out(args.out))
    con.result(f"Report: {path}")
    return 0


def _report_out(value: str | None) -> Path | None:
    """``report --out``: a file in a folder that exists (a typo in the folder must not create it)."""
    if not value:
        return None
    out = Path(value)
    if out.is_dir():
        raise ConfigError("--out", f"{out} is a folder; give the HTML file's path, e.g. {out / 'report.html'}")
    if not out.parent.is_dir():
        raise ConfigError("--out", f"the folder {out.parent} does not exist (create it first, or choose another path)")
    return out


def _existing_run_dir(value: str, what: str, args=None) -> Path:
    """A run folder given as a path or as a run's name (looked up in the runs folders, --robot's first)."""
    from payload_agent.recording.lookup import find_run_dir

    extra = [load_robot(args).storage.runs_dir] if getattr(args, "robot", None) else []
    return find_run_dir(value, what, extra)


def recorded_config(args, run_dir: Path) -> tuple[dict, Config]:
    """The run's manifest, and the config to analyse it with: --robot if given, else the run's own snapshot."""
    from payload_agent.configuration.recorded import parse_recorded_config
    from payload_agent.recording.rundata import check_manifest, load_manifest

    manifest = load_manifest(run_dir)
    source = str(run_dir / "manifest.json")
    check_manifest(manifest, source)
    if getattr(args, "robot", None):
        return manifest, load_robot(args)
    return manifest, parse_recorded_config(manifest["config"], manifest, source)


def cmd_solve(args, con: Console) -> int:
    from payload_agent.solve import solve_run

    from payload_agent.recording.lookup import recorded_solver

    run_dir = _existing_run_dir(args.run_dir, "RUN_DIR", args)
    baseline_dir = _existing_run_dir(args.baseline, "--baseline", args) if args.baseline else None
    if args.history and not args.robot:
        raise ConfigError("--history", "needs --robot: the history belongs to a robot's state folder")
    from payload_agent.recording.imported_run import is_imported
    from payload_agent.recording.rundata import load_manifest

    if is_imported(load_manifest(run_dir)):
        from payload_agent.cli_import import solve_imported

        return solve_imported(run_dir, load_manifest(run_dir), args, con)
    manifest, config = recorded_config(args, run_dir)
    solver = args.solver or recorded_solver(run_dir, manifest)  # the run's own solver, not the YAML's
    solved = solve_run(run_dir, manifest, config, solver=solver, baseline_dir=baseline_dir,
                       result_path=Path(args.result) if args.result else None)
    con.say(solved.table)
    from payload_agent.output.pendant import driver_type_of, pendant_values

    est = solved.result.primary
    passed = bool(solved.result.quality.get("passed", False))
    con.result(f"Baseline: {solved.baseline_text}; solver: {est.solver}; gains: {solved.gains_text}")
    con.result(f"Result written to {solved.path} (the run's own result.json is unchanged)")
    if passed:
        con.result(pendant_values(driver_type_of(manifest), est.mass_kg, est.cog_mm).describe())
    history_id = None
    if args.history:
        history_id = solved.record_history(config, args.tool)
        con.result(f"Added to the history of robot {config.robot.name!r} as #{history_id}")
    code = 0 if passed else QualityGateError.exit_code
    con.emit_json({"ok": passed, "exit_code": code, "result_file": str(solved.path), "history_id": history_id,
                   "result": solved.result.to_json(),
                   "controller_values": pendant_values(driver_type_of(manifest), est.mass_kg, est.cog_mm).to_json()})
    return code


COMMANDS: dict[str, Callable[[Any, Console], int]] = {
    "run": cmd_run, "baseline": cmd_baseline, "calibrate": cmd_calibrate, "watch": cmd_watch, "plan": cmd_plan,
    "doctor": cmd_doctor, "history": cmd_history, "report": cmd_report, "solve": cmd_solve, "import": cmd_import,
    **TOOL_COMMANDS, **VERIFY_COMMANDS, **SERVE_COMMANDS,
}
