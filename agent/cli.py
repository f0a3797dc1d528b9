"""The ``payload-agent`` command: identify the mass and centre of mass of the tool on a robot's flange.

Exit codes (also in ``payload-agent --help``): 0 success / ready; 1 unexpected error (a bug);
2 configuration, plan or safety refusal, or a question nobody could answer (no terminal: pass
--yes or --unattended), or a command-line mistake; 3 robot not ready (including: no stored
baseline fits an unattended run); 4 motion aborted (e-stop, protective stop, supervision,
Ctrl-C or SIGTERM during motion, operator declined after a move); 5 quality gate or data
failure; 6 communication failure (controller unreachable); 130 interrupted by Ctrl-C (SIGINT)
while nothing moved; 143 terminated by SIGTERM while nothing moved.
"""

from __future__ import annotations

import argparse
import signal
import sys
import traceback
from pathlib import Path

from payload_agent.version import __version__
from payload_agent.cli_commands import COMMANDS
from payload_agent.errors import PayloadAgentError, Terminated
from payload_agent.output.console import Console, setup_logging
from payload_agent.tools.library import tool_name_arg

DESCRIPTION = ("Identify the mass and centre of mass of the tool on a robot's flange from point-to-point "
               "joint moves and the joint angles and motor currents the controller reports (no force sensor, "
               "no custom trajectories). It plans and safety-checks a short sequence of joint sweeps, asks, "
               "moves, records, solves, reports, and on request writes the payload to the controller.")
EPILOG = """\
typical use:
  payload-agent doctor --robot ec66                 is the robot reachable and ready? (never moves)
  payload-agent plan --robot ec66 --connect         every move and the safety verdict (never moves)
  payload-agent baseline --robot ec66               once, tool removed: the empty-flange reference
  payload-agent run --robot ec66 [--apply]          after each tool change
  payload-agent run --robot ec66 --unattended --apply --json     from a cell controller or cron

--robot NAME finds NAME.yaml in ./configs, $XDG_CONFIG_HOME/payload-agent/robots, the folders
in $PAYLOAD_AGENT_ROBOTS, then the robot files shipped with the package; a path to a YAML file works too. State (baseline, calibration, history)
and run folders live in $XDG_STATE_HOME/payload-agent/<robot>/ unless the YAML's storage section
says otherwise.

exit codes:
  0    success (doctor: ready)
  1    unexpected error (a bug; -v shows the traceback)
  2    configuration, plan or safety refusal; no terminal to ask on (pass --yes or --unattended)
  3    robot not ready (state, mode, stored baseline or calibration; doctor: not ready)
  4    motion aborted (e-stop, protective stop, supervision trip, Ctrl-C or SIGTERM during motion)
  5    quality gate or data failure (result kept, nothing written to the controller)
  6    communication failure (controller unreachable or answering nonsense; a payload write that did not take)
  7    verify: the mounted tool does not match the expected payload (what differs is printed)
  130  interrupted by Ctrl-C while nothing moved
  143  terminated by SIGTERM while nothing moved
"""
CLIENT_LIBRARIES = ("ur_rtde", "pymodbus", "pyserial", "python-can", "canopen", "mujoco", "numpy", "scipy",
                    "matplotlib", "PyYAML")




def version_text() -> str:
    """This version, Python, and the installed client libraries the drivers use (their versions matter)."""
    from importlib.metadata import PackageNotFoundError, version

    lines = [f"payload-agent {__version__} (Python {sys.version.split()[0]})"]
    for name in CLIENT_LIBRARIES:
        try:
            lines.append(f"  {name} {version(name)}")
        except PackageNotFoundError:
            lines.append(f"  {name} not installed")
    try:
        from payload_agent.drivers.registry import available

        lines.append("  drivers: " + ", ".join(available()))
    except Exception as exc:  # a broken third-party entry point must not break --version
        lines.append(f"  drivers: unavailable ({exc})")
    return "\n".join(lines)


class _VersionAction(argparse.Action):
    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(version_text())
        parser.exit()


def _common(json_ok: bool) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("output")
    g.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="more detail: every move, library messages, tracebacks of unexpected errors")
    g.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="only warnings, errors and the final result")
    if json_ok:
        g.add_argument("--json", action="store_true",
                       help="print one JSON document on stdout (human text goes to stderr)")
    return p


def _robot_arg(p: argparse.ArgumentParser, required: bool = True, what: str = "") -> None:
    p.add_argument("--robot", required=required, metavar="NAME|YAML",
                   help=what or "robot YAML file, or NAME to find NAME.yaml in ./configs, "
                                "$XDG_CONFIG_HOME/payload-agent/robots, $PAYLOAD_AGENT_ROBOTS or the shipped robots")


def _session_args(p: argparse.ArgumentParser, report: bool = True) -> None:
    p.add_argument("--unattended", action="store_true",
                   help="never prompt: fail with an exit code where a person would be asked (cell controllers, cron)")
    p.add_argument("--yes", action="store_true",
                   help="accept the shown plan without asking (tool changes are still asked for)")
    p.add_argument("--fresh-baseline", action="store_true",
                   help="record the empty-flange run in this session even if a stored baseline fits")
    if report:
        p.add_argument("--no-report", action="store_true", help="do not write report.html into the run folder")
    p.add_argument("--retry-sweeps", type=int, default=0, metavar="N",
                   help="redo a sweep whose sample stream had a gap, up to N times per run phase (default 0: abort)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="payload-agent", description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action=_VersionAction,
                   help="show the version, Python, the drivers' client libraries and the installed drivers")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more detail (also after the command)")
    p.add_argument("-q", "--quiet", action="store_true", default=False,
                   help="only warnings, errors and the final result (also after the command)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name: str, help: str, json_ok: bool = False) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=help, description=help[0].upper() + help[1:] + ".",
                              parents=[_common(json_ok)])

    run = add("run", "identify the payload on the robot (moves the robot)", json_ok=True)
    _robot_arg(run)
    _session_args(run)
    run.add_argument("--apply", action="store_true",
                     help="write the result to the controller (only if the quality checks pass), then read it back")
    run.add_argument("--tool", type=tool_name_arg, help="the mounted tool's name: history compares results per "
                                                         "tool, and a result that passes is stored in the tool library")
    run.add_argument("--result", metavar="PATH", help="also write the result JSON to this path")
    run.add_argument("--solver", choices=["three-step", "general"], help="override procedure.solver")
    run.add_argument("--resume", metavar="RUN_DIR",
                     help="finish an incomplete run folder: same robot, YAML and plan; only its unfinished sweeps "
                          "are recorded")

    base = add("baseline", "record and store the empty-flange run (remove the tool first; moves the robot)")
    _robot_arg(base)
    _session_args(base, report=False)

    cal = add("calibrate", "fit the drive gains from a run with a known reference payload (moves the robot; "
                           "on a simulated robot the reference named here is the simulated tool)")
    _robot_arg(cal)
    cal.add_argument("--known-mass", type=float, required=True, metavar="KG", help="reference payload mass, kg")
    cal.add_argument("--known-cog", required=True, metavar="X,Y,Z",
                     help="reference centre of mass in mm, flange frame, e.g. 0,0,80")
    cal.add_argument("--speed-percent", type=float, metavar="PERCENT",
                     help="the calibration's sweep speed instead of the YAML's procedure.speed_percent: slower pins "
                          "the drive gains tighter, and every later run carries their uncertainty (a calibration is "
                          "run once per robot, not per tool)")
    cal.add_argument("--procedure", metavar="NAME|FILE",
                     help="the procedure to calibrate on instead of the YAML's procedure.name: a bundled procedure's "
                          "name or a procedure file (its sweep range and speeds stay the YAML's unless given "
                          "below; the inertia part is left out). A calibration on the procedure your runs sweep takes "
                          "most of the arm's DH-length error out of their σ, e.g. the one `plan --target-std` chose")
    cal.add_argument("--sweep-deg", metavar="FROM,TO", help="the calibration's sweep range instead of the YAML's "
                                                            "procedure.sweep_deg (link elevation, degrees)")
    cal.add_argument("--travel-speed-percent", type=float, metavar="PERCENT",
                     help="the calibration's travel speed instead of the YAML's procedure.travel_speed_percent")
    cal.add_argument("--accel-percent", type=float, metavar="PERCENT",
                     help="the calibration's acceleration instead of the YAML's procedure.accel_percent. With "
                          "--procedure and --speed-percent these make the calibration's plan a candidate's of `plan "
                          "--target-std`: `plan` then offers that plan, whose run reuses the calibration's empty run "
                          "and shares its noise (a σ up to a fifth tighter, no empty run of its own)")
    cal.add_argument("--park", action="store_true",
                     help="end with one more travel move back to the plan's first pose (`plan --park` shows it; the "
                          "safety gate checks it with the whole plan before the first move): the arm waits there for "
                          "the tool change, and a run of the calibration's plan then starts with no approach and "
                          "reuses its empty run (what `plan --target-std` advises for a fast run)")
    _session_args(cal)

    hist = add("history", "list past identifications of this robot", json_ok=True)
    _robot_arg(hist)
    hist.add_argument("--tool", help="only this tool label")
    hist.add_argument("--limit", type=int, metavar="N", help="only the last N entries")

    rep = add("report", "write the HTML report of a recorded run folder (finished or stopped)")
    rep.add_argument("run_dir", metavar="RUN_DIR", help="the run folder: its path, or its name as `history` shows it")
    _robot_arg(rep, required=False, what="robot YAML or NAME to use instead of the config stored in the run "
                                         "(also locates the history shown in the report)")
    rep.add_argument("--out", metavar="PATH", help="where to write the HTML (default RUN_DIR/report.html)")

    watch = add("watch", "wait for the configured tool-change signal, then run unattended with --apply")
    _robot_arg(watch)
    watch.add_argument("--max-runs", type=int, metavar="N", help="stop after this many runs (default: until SIGTERM)")
    watch.add_argument("--tool", help="the tool assumed when the trigger names none (a trigger file's first line "
                                      "names the tool): a library tool is verified, a new one identified")

    plan = add("plan", "print every move and the safety verdict; checks everything run checks, never moves",
               json_ok=True)
    _robot_arg(plan)
    plan.add_argument("--from-deg", metavar="J1,...,J6",
                      help="current joint angles in degrees, to check the approach move too")
    plan.add_argument("--connect", action="store_true",
                      help="connect to the controller to read where the robot stands (nothing moves)")
    plan.add_argument("--park", action="store_true",
                      help="show and check the plan as `calibrate --park` runs it: ending at its first pose")
    plan.add_argument("--target-std", metavar="G,MM",
                      help="predict the uncertainty (1σ: mass in g, centre of mass in mm) of candidate procedures "
                           "before moving and show the fastest that meets it")
    plan.add_argument("--payload-kg", type=float, metavar="KG",
                      help="with --target-std: the expected payload's mass (default: a nominal 2 kg)")
    plan.add_argument("--payload-cog-mm", metavar="X,Y,Z",
                      help="with --target-std: the expected payload's centre of mass, flange frame")
    plan.add_argument("--tool", metavar="NAME", help="with --target-std: expect the tool library's payload NAME")

    solve = add("solve", "re-run the analysis of a recorded run folder into a new result file (never overwrites)",
                json_ok=True)
    solve.add_argument("run_dir", metavar="RUN_DIR", help="the run folder, its path or its name as `history` shows it "
                                                          "(it alone is read: manifest and CSVs)")
    solve.add_argument("--baseline", metavar="RUN_DIR",
                       help="another run folder whose empty-flange phase to subtract instead of the run's own")
    _robot_arg(solve, required=False, what="robot YAML or NAME whose kinematics to use instead of the config "
                                           "stored in the run (needed for --history)")
    solve.add_argument("--solver", choices=["three-step", "general"],
                       help="override the solver the run used (recorded in its manifest)")
    solve.add_argument("--result", metavar="PATH",
                       help="write the result here (default RUN_DIR/result-solve-<time>.json); never overwritten")
    solve.add_argument("--history", action="store_true",
                       help="also add the result to the robot's history (needs --robot); left alone otherwise")
    solve.add_argument("--tool", help="with --history: the tool label to record")

    imp = add("import", "identify the payload from two recordings of one motion the agent did not make "
                        "(RTDE CSV; never moves)", json_ok=True)
    _robot_arg(imp, what="robot YAML or NAME whose kinematics the recordings are analysed with")
    imp.add_argument("--empty", required=True, metavar="FILE", help="the recording with the empty flange")
    imp.add_argument("--loaded", required=True, metavar="FILE", help="the same motion with the tool mounted")
    imp.add_argument("--columns", metavar="MAP",
                     help="the columns of a file without a header line, in order: name[count] for a vector, - to "
                          "skip, e.g. timestamp,actual_q[6],actual_qd[6],actual_current[6],target_current[6],"
                          "target_moment[6] (RTDE names; a header line names them itself)")
    imp.add_argument("--gains", choices=["controller", "config"], default="controller",
                     help="current-to-torque constants: fitted from the controller's target_current and "
                          "target_moment (default), or the robot YAML's effort.gains_nm_per_unit")

    doc = add("doctor", "connect and check that the robot is ready for a run; never moves", json_ok=True)
    _robot_arg(doc)
    doc.add_argument("--seconds", type=float, default=2.0, metavar="S",
                     help="how long to measure the sample stream (default 2)")
    from payload_agent.tools.commands import add_parsers as add_tool_parsers
    from payload_agent.verify_command import add_parser as add_verify_parser
    from payload_agent.plc.commands import add_parser as add_serve_parser

    add_tool_parsers(add, _robot_arg)
    add_verify_parser(add, _robot_arg)
    add_serve_parser(add, _robot_arg)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    verbosity = -1 if getattr(args, "quiet", False) else int(getattr(args, "verbose", 0) or 0)
    con = Console(verbosity, bool(getattr(args, "json", False)))
    setup_logging(verbosity, con.stderr)
    previous = None
    if args.command not in ("watch", "serve"):  # watch and serve handle their signals themselves (one run at a time, clean exit)
        previous = _install_sigterm()
    try:
        return COMMANDS[args.command](args, con)
    except PayloadAgentError as exc:
        con.error(f"payload-agent: error: {exc}")
        partial = _partial(exc, getattr(args, "robot", None))
        if partial.get("continue_with"):
            con.error(f"Continue it with: {partial['continue_with']}")
        con.emit_json({"ok": False, "error": str(exc), "error_type": type(exc).__name__,
                       "exit_code": exc.exit_code, **partial})
        return exc.exit_code
    except Terminated:
        con.error("payload-agent: terminated (SIGTERM); nothing was moving")
        con.emit_json({"ok": False, "error": "terminated", "exit_code": 143})
        return 143
    except KeyboardInterrupt:
        con.error("payload-agent: interrupted (Ctrl-C); nothing was moving")
        con.emit_json({"ok": False, "error": "interrupted", "exit_code": 130})
        return 130
    except Exception as exc:  # a bug: say so in one line; the traceback with -v and in the run log
        import logging

        logging.getLogger("payload_agent").debug("unexpected error", exc_info=True)
        con.error(f"payload-agent: unexpected error: {type(exc).__name__}: {exc} (this is a bug; "
                  + ("traceback below" if verbosity > 0 else "-v shows the traceback") + ")")
        if verbosity > 0:
            traceback.print_exc(file=con.stderr)
        con.emit_json({"ok": False, "error": f"{type(exc).__name__}: {exc}", "exit_code": 1})
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _partial(exc: BaseException, robot: str | None = None) -> dict:
    """What a failed command still produced (a run's outcome on a failed quality gate, a run folder) and the
    command that continues that run folder."""
    out = {}
    outcome = getattr(exc, "outcome", None)
    if outcome is not None:
        from payload_agent.cli_commands import outcome_json

        out["outcome"] = outcome_json(outcome)
    run_dir = getattr(exc, "run_dir", None)
    if run_dir is not None:
        from payload_agent.session.resume import continue_command

        out["run_dir"] = str(Path(run_dir))
        out["continue_with"] = continue_command(Path(run_dir), robot)
    return out


def _install_sigterm():
    def handler(signum, frame):
        raise Terminated()

    try:
        return signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread (embedded use): leave signals alone
        return None


if __name__ == "__main__":
    sys.exit(main())
