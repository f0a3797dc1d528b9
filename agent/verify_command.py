"""`payload-agent verify`: the command line of ``session.verify`` (registered by cli.py and cli_commands.py)."""

from __future__ import annotations

import argparse
from typing import Any, Callable

from payload_agent.tools.library import tool_name_arg


def add_parser(add: Callable[..., argparse.ArgumentParser], robot_arg: Callable[..., None]) -> None:
    p = add("verify", "test in a few seconds of motion whether the mounted tool is the expected one (moves the "
                      "robot): a library tool, or the controller's current payload setting", json_ok=True)
    robot_arg(p)
    p.add_argument("--tool", type=tool_name_arg, metavar="NAME",
                   help="the library tool expected on the flange (default: the controller's current payload setting)")
    p.add_argument("--apply", action="store_true",
                   help="when the tool matches and the controller's payload setting does not, write the library's "
                        "payload and read it back")
    p.add_argument("--unattended", action="store_true", help="never prompt (cell controllers)")
    p.add_argument("--yes", action="store_true", help="accept the shown verify motion without asking")
    p.add_argument("--mass-limit-percent", type=float, default=5.0, metavar="P",
                   help="mass error the test must find with 95 %% power at 1 %% false alarms (default 5)")
    p.add_argument("--cog-limit-mm", type=float, default=10.0, metavar="MM",
                   help="centre-of-mass shift the test must find with 95 %% power (default 10)")


def cmd_verify(args, con) -> int:
    from payload_agent.configuration.config import load_config
    from payload_agent.configuration.paths import find_robot
    from payload_agent.errors import ToolMismatchError
    from payload_agent.recording.state import describe_locations
    from payload_agent.session.preflight import preflight
    from payload_agent.session.verify import VerifyOptions, verify_tool

    config = load_config(find_robot(args.robot))
    preflight(config, calibration=True, apply=args.apply).require()
    con.say(describe_locations(config))
    opts = VerifyOptions(tool=args.tool, unattended=args.unattended, assume_yes=args.yes, apply=args.apply,
                         mass_limit_percent=args.mass_limit_percent, cog_limit_mm=args.cog_limit_mm, out=con.say,
                         ask=con.asker("Pass --yes to accept the verify motion, or --unattended."), detail=con.detail)
    try:
        outcome = verify_tool(config, opts)
    except ToolMismatchError as exc:
        con.emit_json({"ok": False, "error": str(exc), "exit_code": exc.exit_code, "verdict": "mismatch",
                       **exc.outcome.to_json()})
        con.error(f"payload-agent: {exc}")
        return exc.exit_code
    con.result(f"Tool verified: {outcome.result.describe(opts.tool or 'the controller setting')}")
    con.emit_json({"ok": True, "verdict": "match", **outcome.to_json()})
    return 0


VERIFY_COMMANDS: dict[str, Callable[[Any, Any], int]] = {"verify": cmd_verify}
