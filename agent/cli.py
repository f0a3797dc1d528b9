"""The ``payload-agent`` command.

Exit codes: 0 success, 1 unexpected error, 2 configuration/plan/safety refusal,
3 robot not ready, 4 motion aborted, 5 quality gate or data failure,
6 communication failure, 130 interrupted outside motion.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from payload_agent import __version__
from payload_agent.config import load_config
from payload_agent.errors import PayloadAgentError


def _cmd_run(args) -> int:
    from payload_agent.runner import RunOptions, run_identification

    config = load_config(args.robot)
    opts = RunOptions(unattended=args.unattended, assume_yes=args.yes,
                      result_path=Path(args.result) if args.result else None, solver=args.solver)
    run_identification(config, opts)
    return 0


def _cmd_plan(args) -> int:
    import numpy as np

    from payload_agent.planner import expected_durations, make_plan
    from payload_agent.runner import describe_plan
    from payload_agent.safety import SafetyGate

    config = load_config(args.robot)
    plan = make_plan(config)
    start = None
    if args.from_deg:
        start = np.radians([float(v) for v in args.from_deg.split(",")])
    print(describe_plan(plan, expected_durations(plan, start)))
    verdict = SafetyGate(config).check(plan, start)
    print("Safety gate: " + verdict.describe())
    return 0 if verdict.ok or (start is None and len(verdict.problems) == 1) else 2


def _cmd_solve(args) -> int:
    from payload_agent.rundata import load_manifest
    from payload_agent.config import parse_config
    from payload_agent.results import format_table
    from payload_agent.runner import analyse

    run_dir = Path(args.run_dir)
    manifest = load_manifest(run_dir)
    config = load_config(args.robot) if args.robot else parse_config(manifest["config"],
                                                                     source=f"{run_dir}/manifest.json")
    result = analyse(config, run_dir, solver=args.solver,
                     baseline_dir=Path(args.baseline) if args.baseline else None)
    print(format_table(result, manifest.get("simulation_truth")))
    if args.result:
        result.write(Path(args.result))
    return 0


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
    run.set_defaults(func=_cmd_run)

    plan = sub.add_parser("plan", help="print every move and the safety verdict, without connecting")
    plan.add_argument("--robot", required=True)
    plan.add_argument("--from-deg", help="current joint angles, comma-separated, to check the approach move")
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
