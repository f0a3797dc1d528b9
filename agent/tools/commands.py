"""`payload-agent tools list|show|remove|export|import`: the robot's tool library from the command line.

Registered by ``cli.py`` (``add_parsers``) and ``cli_commands.COMMANDS`` (``TOOL_COMMANDS``); none of
these commands connects to the robot.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Callable

from payload_agent.tools import library, transfer


def add_parsers(add: Callable[..., argparse.ArgumentParser], robot_arg: Callable[..., None]) -> None:
    tools = add("tools", "the robot's tool library: list, show, remove, export, import (never connects)",
                json_ok=True)
    robot_arg(tools)
    tools.add_argument("action", choices=["list", "show", "remove", "export", "import"],
                       help="list every tool; show one with its history; remove one (its history stays); export "
                            "the library to JSON; import a JSON export (another cell's tools)")
    tools.add_argument("name", nargs="?", metavar="NAME|FILE",
                       help="show/remove: the tool's name; export/import: the JSON file (export: default stdout)")
    tools.add_argument("--replace", action="store_true", help="import: replace tools of the same name")
    tools.add_argument("--number", type=int, metavar="N",
                       help="show: the tool by its number (what a PLC or tool changer sends) instead of its name")


def library_of(args) -> tuple[Any, Path]:
    from payload_agent.configuration.config import load_config
    from payload_agent.configuration.paths import find_robot
    from payload_agent.recording.state import RobotState

    config = load_config(find_robot(args.robot))
    return config, library.tool_library_path(RobotState.for_config(config).root)


def _need_name(args, what: str) -> str:
    from payload_agent.errors import ConfigError

    if not args.name:
        raise ConfigError("tools " + args.action, f"give the {what} (payload-agent tools {args.action} {what.upper()})")
    return args.name


def cmd_tools(args, con) -> int:
    config, db = library_of(args)
    robot = config.robot.name
    if args.action == "list":
        tools = library.list_tools(db, robot)
        if not tools:
            con.say(f"No tools in the library of robot {robot!r} ({db}); `payload-agent run --tool NAME` adds one.")
        for t in tools:
            con.result(f"{t.describe()}  [{t.source} {t.time_utc}]")
        con.emit_json({"ok": True, "robot": robot, "library": str(db), "tools": [t.to_json() for t in tools]})
        return 0
    if args.action == "show":
        if args.number is not None:
            entry = library.by_number(db, robot, args.number)
            if entry is None:
                from payload_agent.errors import DataError

                raise DataError(f"no tool with number {args.number} in the tool library of robot {robot} ({db})")
        else:
            entry = library.require(db, robot, _need_name(args, "name"))
        hist = library.versions(db, robot, entry.name)
        con.result(entry.describe())
        con.say(f"  from run {entry.run_dir or '(none recorded)'}; {entry.source} {entry.time_utc}"
                + (f"; {entry.note}" if entry.note else ""))
        for line in inertia_lines(entry):
            con.result(line)
        con.say("History:")
        for v in hist:
            con.say(f"  #{v.id} {v.entry.time_utc} {v.action}: {v.entry.mass_kg:.4f} kg, "
                    f"[{', '.join(f'{c:.1f}' for c in v.entry.cog_mm)}] mm ({v.entry.run_dir or 'no run'})")
        con.emit_json({"ok": True, "robot": robot, "tool": entry.to_json(),
                       "history": [{"id": v.id, "action": v.action, **v.entry.to_json()} for v in hist]})
        return 0
    if args.action == "remove":
        entry = library.remove(db, robot, _need_name(args, "name"))
        con.result(f"Removed {entry.describe()} (its history stays in {db})")
        con.emit_json({"ok": True, "robot": robot, "removed": entry.to_json()})
        return 0
    if args.action == "export":
        doc = transfer.export_document(db, robot)
        text = json.dumps(doc, indent=2) + "\n"
        if args.name:
            Path(args.name).write_text(text, encoding="utf-8")
            con.say(f"Exported {len(doc['tools'])} tool(s) of robot {robot} to {args.name}")
            con.emit_json({"ok": True, "robot": robot, "file": args.name, "count": len(doc["tools"])})
        elif con.json_mode:
            con.emit_json({"ok": True, **doc})
        else:
            con.result(text.rstrip("\n"))
        return 0
    stored, skipped = transfer.import_file(db, robot, Path(_need_name(args, "file")), replace=args.replace)
    for e in stored:
        con.result(f"Imported {e.describe()}")
    if skipped:
        con.say(f"Kept the library's own entries for {', '.join(skipped)} (pass --replace to overwrite them)")
    con.emit_json({"ok": True, "robot": robot, "imported": [e.name for e in stored], "skipped": skipped})
    return 0


def inertia_lines(entry: library.ToolEntry) -> list[str]:
    """What `tools show` says about the inertia and the covariance of mass and centre of mass."""
    lines = []
    principal = entry.principal_inertia()
    if principal is None:
        lines.append("  inertia: not identified (a run with the wrist moves, procedure.inertia, identifies it)")
    else:
        moments, abc = principal
        std = entry.inertia_com_std_kgm2
        lines.append("  inertia about the CoM [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] kg·m²: "
                     + ", ".join(f"{v:.5f}" for v in entry.inertia_com_kgm2)  # type: ignore[union-attr]
                     + ("" if std is None else " ± " + ", ".join(f"{1.96 * v:.5f}" for v in std) + " (95 %)"))
        lines.append("  principal moments JX, JY, JZ kg·m²: " + ", ".join(f"{v:.5f}" for v in moments)
                     + "; axes A, B, C (z-y'-x'' from the flange axes): " + ", ".join(f"{v:.1f}" for v in abc) + "°")
    cov = entry.covariance_theta_si
    if cov is not None:
        import numpy as np

        c = np.asarray(cov, float)
        d = np.sqrt(np.maximum(np.diag(c), 1e-300))
        r = c / np.outer(d, d)
        lines.append("  covariance of [m, m·cx, m·cy, m·cz] stored (verify uses it); correlations of m with m·c: "
                     + ", ".join(f"{v:+.2f}" for v in r[0, 1:]))
    return lines


TOOL_COMMANDS: dict[str, Callable[[Any, Any], int]] = {"tools": cmd_tools}
