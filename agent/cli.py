"""The ``payload-agent`` command.

Exit codes: 0 success, 1 unexpected error, 2 configuration/plan/safety refusal,
3 robot not ready (including: no stored baseline fits), 4 motion aborted,
5 quality gate or data failure, 6 communication failure, 130 interrupted outside motion.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from payload_agent import __version__
from payload_agent.configuration.config import load_config
from payload_agent.errors import ConfigError, PayloadAgentError, QualityGateError


def _run_options(args, mode: str, **extra):
    from payload_agent.session.runner import RunOptions

    return RunOptions(mode=mode, unattended=args.unattended, assume_yes=args.yes,
                      result_path=Path(args.result) if getattr(args, "result", None) else None,
                      solver=getattr(args, "solver", None), tool=getattr(args, "tool", None),
                      fresh_baseline=getattr(args, "fresh_baseline", False),
                      report=not getattr(args, "no_report", False),
                      retry_sweeps=getattr(args, "retry_sweeps", 0) or 0,
                      resume=Path(args.resume) if getattr(args, "resume", None) else None, **extra)


def _cmd_run(args) -> int:
    from payload_agent.session.runner import run_identification

    config = load_config(args.robot)
    run_identification(config, _run_options(args, "identify", apply=args.apply))
    return 0


def _cmd_baseline(args) -> int:
    from payload_agent.session.runner import run_identification

    config = load_config(args.robot)
    run_identification(config, _run_options(args, "baseline"))
    return 0


def _cmd_calibrate(args) -> int:
    from payload_agent.types import PayloadSetting
    from payload_agent.session.runner import run_identification

    config = load_config(args.robot)
    try:
        cog = [float(v) for v in args.known_cog.split(",")]
        if len(cog) != 3:
            raise ValueError
    except ValueError:
        raise ConfigError("--known-cog", f"expected three numbers in mm separated by commas, got {args.known_cog!r}")
    if not 0 < args.known_mass < 100:
        raise ConfigError("--known-mass", f"expected the reference payload's mass in kg, got {args.known_mass:g}")
    ref = PayloadSetting(mass_kg=args.known_mass, cog_m=tuple(v / 1000.0 for v in cog))
    run_identification(config, _run_options(args, "calibrate", reference=ref))
    return 0


def _cmd_history(args) -> int:
    from payload_agent.output import history
    from payload_agent.recording.state import RobotState

    config = load_config(args.robot)
    db = RobotState.for_config(config).history_db
    if not db.exists():
        print(f"No history yet for robot {config.robot.name!r} ({db}).")
        return 0
    entries = history.entries(db, tool=args.tool, limit=args.limit)
    print(history.format_history(entries, history.compare_to_previous(entries)))
    return 0


def _cmd_report(args) -> int:
    from payload_agent.output.report import write_report
    from payload_agent.recording.rundata import load_manifest
    from payload_agent.recording.state import RobotState

    run_dir = Path(args.run_dir)
    config = _run_config(args, run_dir, load_manifest(run_dir))
    db = RobotState.for_config(config).history_db
    path = write_report(run_dir, config, history_db=db if db.exists() else None,
                        out_path=Path(args.out) if args.out else None)
    print(f"Report: {path}")
    return 0


def _cmd_watch(args) -> int:
    from payload_agent.session.connection import build_driver
    from payload_agent.session.runner import RunOptions, run_identification
    from payload_agent.session.watch import watch

    config = load_config(args.robot)
    cell = None
    if config.simulation is not None:  # one simulated cell for the whole watch: its inputs can be set
        from payload_agent.session.simulation import SimulatedCell

        cell = SimulatedCell(config).start()

    def run_once() -> int:
        run_identification(config, RunOptions(unattended=True, apply=True, tool=args.tool, cell=cell))
        return 0

    try:
        return watch(config, run_once, max_runs=args.max_runs,
                     driver_factory=lambda: build_driver(config, cell.options if cell else None))
    finally:
        if cell is not None:
            cell.close()


def _cmd_plan(args) -> int:
    import numpy as np

    from payload_agent.session.baseline import status_line
    from payload_agent.motion.planner import expected_durations, make_plan
    from payload_agent.session.runner import describe_plan
    from payload_agent.recording.state import RobotState
    from payload_agent.motion.safety import SafetyGate

    from payload_agent.session.connection import build_driver

    config = load_config(args.robot)
    plan = make_plan(config)
    build_driver(config)  # the driver section and effort unit, checked without connecting
    start = None
    if args.from_deg and args.connect:
        raise ConfigError("--from-deg", "give either --from-deg or --connect, not both")
    if args.from_deg:
        try:
            start = np.radians([float(v) for v in args.from_deg.split(",")])
        except ValueError:
            raise ConfigError("--from-deg", f"expected six joint angles in degrees separated by commas, "
                              f"got {args.from_deg!r}") from None
        if start.shape != (6,):
            raise ConfigError("--from-deg", f"expected six joint angles, got {start.size}")
    elif args.connect:
        from payload_agent.session.connection import read_current_q

        start = read_current_q(config)
        print("Robot stands at [" + ", ".join(f"{v:.2f}" for v in np.degrees(start)) + "] deg")
    print(describe_plan(plan, expected_durations(plan, start)))
    print(status_line(RobotState.for_config(config), config, plan))
    verdict = SafetyGate(config).check(plan, start)
    print("Safety gate: " + verdict.describe())
    if verdict.ok or (start is None and len(verdict.problems) == 1):
        return 0
    print(f"payload-agent: error: {config.source}: the safety gate refused the plan:\n"
          + "\n".join(f"  - {p}" for p in verdict.problems), file=sys.stderr)
    return 2


def _run_config(args, run_dir: Path, manifest: dict):
    """The config a recorded run is analysed with: --robot if given, else the one stored in its manifest."""
    from payload_agent.configuration.config import parse_config

    if args.robot:
        return load_config(args.robot)
    return parse_config(manifest["config"], source=f"{run_dir}/manifest.json")


def _cmd_solve(args) -> int:
    from payload_agent.recording.rundata import load_manifest
    from payload_agent.solvers.results import format_table
    from payload_agent.session.runner import analyse

    run_dir = Path(args.run_dir)
    manifest = load_manifest(run_dir)
    config = _run_config(args, run_dir, manifest)
    result = analyse(config, run_dir, solver=args.solver,
                     baseline_dir=Path(args.baseline) if args.baseline else None)
    print(format_table(result, manifest.get("simulation_truth")))
    if args.result:
        result.write(Path(args.result))
    return 0 if result.quality.get("passed", False) else QualityGateError.exit_code


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="payload-agent", description=__doc__.split("\n")[0])
    p.add_argument("--version", action="version", version=f"payload-agent {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="identify the payload on the robot (moves the robot)")
    run.add_argument("--robot", required=True, help="robot YAML (configs/*.yaml)")
    run.add_argument("--unattended", action="store_true", help="never prompt; fail instead of asking")
    run.add_argument("--yes", action="store_true", help="accept the shown plan without asking")
    run.add_argument("--result", help="also write the result JSON to this path")
    run.add_argument("--solver", choices=["three-step", "general"], help="override procedure.solver")
    run.add_argument("--apply", action="store_true",
                     help="write the result to the controller (only if the quality checks pass), then read it back")
    run.add_argument("--tool", help="a label for the mounted tool (history compares results per tool)")
    run.add_argument("--fresh-baseline", action="store_true",
                     help="record the empty-flange run in this session even if a stored baseline fits")
    run.add_argument("--no-report", action="store_true", help="do not write report.html")
    run.add_argument("--retry-sweeps", type=int, default=0, metavar="N",
                     help="redo a sweep whose sample stream had a gap, up to N times per run phase (default 0: abort)")
    run.add_argument("--resume", metavar="RUN_DIR",
                     help="finish an incomplete run folder: same robot, YAML and plan; only unfinished sweeps are "
                          "recorded")
    run.set_defaults(func=_cmd_run)

    base = sub.add_parser("baseline", help="record and store the empty-flange run (remove the tool first)")
    base.add_argument("--robot", required=True)
    base.add_argument("--unattended", action="store_true", help="never prompt (the flange is known to be empty)")
    base.add_argument("--yes", action="store_true", help="accept the shown plan without asking")
    base.set_defaults(func=_cmd_baseline)

    cal = sub.add_parser("calibrate", help="fit the drive gains from a run with a known reference payload")
    cal.add_argument("--robot", required=True)
    cal.add_argument("--known-mass", type=float, required=True, help="reference payload mass, kg")
    cal.add_argument("--known-cog", required=True, help="reference centre of mass X,Y,Z in mm (flange frame)")
    cal.add_argument("--unattended", action="store_true")
    cal.add_argument("--yes", action="store_true")
    cal.add_argument("--fresh-baseline", action="store_true")
    cal.add_argument("--no-report", action="store_true")
    cal.set_defaults(func=_cmd_calibrate)

    hist = sub.add_parser("history", help="list past identifications of this robot")
    hist.add_argument("--robot", required=True)
    hist.add_argument("--tool", help="only this tool label")
    hist.add_argument("--limit", type=int, help="only the last N entries")
    hist.set_defaults(func=_cmd_history)

    rep = sub.add_parser("report", help="write the HTML report of a recorded run")
    rep.add_argument("run_dir")
    rep.add_argument("--robot", help="robot YAML to use instead of the config stored in the run")
    rep.add_argument("--out", help="where to write the HTML (default RUN_DIR/report.html)")
    rep.set_defaults(func=_cmd_report)

    watch = sub.add_parser("watch", help="wait for the configured tool-change signal, then run unattended with --apply")
    watch.add_argument("--robot", required=True)
    watch.add_argument("--max-runs", type=int, help="stop after this many runs (default: until SIGTERM)")
    watch.add_argument("--tool", help="tool label recorded with each run")
    watch.set_defaults(func=_cmd_watch)

    plan = sub.add_parser("plan", help="print every move and the safety verdict, without connecting")
    plan.add_argument("--robot", required=True)
    plan.add_argument("--from-deg", help="current joint angles, comma-separated, to check the approach move")
    plan.add_argument("--connect", action="store_true",
                      help="connect to the controller (nothing moves) to check the approach from where it stands")
    plan.set_defaults(func=_cmd_plan)

    solve = sub.add_parser("solve", help="re-run segmentation and solving on a recorded run folder")
    solve.add_argument("run_dir")
    solve.add_argument("--baseline", help="run folder whose empty phase to use")
    solve.add_argument("--robot", help="robot YAML to use instead of the config stored in the run")
    solve.add_argument("--solver", choices=["three-step", "general"])
    solve.add_argument("--result", help="also write the result JSON to this path")
    solve.set_defaults(func=_cmd_solve)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except PayloadAgentError as exc:
        print(f"payload-agent: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("payload-agent: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
