"""A tool change at production speed: verify a known tool and write its stored payload; identify only a new
or mismatching one.

What `watch` (a trigger naming the tool), the PLC servers and ``payload_agent.tool_changed`` call. The tool is
named by its library name or its number (what a PLC or a tool changer sends, ``ToolEntry.number``):

- a library tool: ``verify`` (seconds of motion) with ``apply``: a match writes the library's payload when
  the controller's setting differs and reads it back;
- a mismatch (``ToolMismatchError``): said, then identified in full under the same name, written
  (``--apply``: only when the quality checks pass) and stored in the library;
- a name the library does not have: identified in full and stored under it;
- no name at all: an identification as `watch` always made, with the result written and not stored.

Every path is an ordinary unattended session (the robot lock, the safety gate, stop and keep the data on
faults); errors propagate as the project's exceptions with their exit codes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from payload_agent.configuration.config import Config
from payload_agent.errors import DataError, ToolMismatchError
from payload_agent.recording.state import RobotState
from payload_agent.tools import library


@dataclass(frozen=True)
class ToolChangeResult:
    tool: str | None
    action: str  # verified | identified-new | identified-mismatch | identified-unnamed
    robot_time_s: float | None  # the verify's (approach included); None for a full identification
    mass_kg: float | None
    cog_mm: tuple[float, float, float] | None
    applied: bool
    run_dirs: tuple[str, ...]
    detail: str

    def to_json(self) -> dict[str, Any]:
        return {"tool": self.tool, "action": self.action, "robot_time_s": self.robot_time_s, "mass_kg": self.mass_kg,
                "cog_mm": None if self.cog_mm is None else list(self.cog_mm), "applied": self.applied,
                "run_dirs": list(self.run_dirs), "detail": self.detail}


def resolve_tool(config: Config, tool: str | None) -> str | None:
    """A trigger's tool: a library name, a library tool number ("3"), a new name, or None (unnamed)."""
    if tool is None or not str(tool).strip():
        return None
    text = str(tool).strip()
    db = library.tool_library_path(RobotState.for_config(config).root)
    if text.isdigit():
        entry = library.by_number(db, config.robot.name, int(text))
        if entry is None:
            raise DataError(f"tool number {text}: no tool of robot {config.robot.name} has this number ({db}); "
                            "give the tool a number in the library (tools import) or send its name")
        return entry.name
    return library.check_name(text, "the trigger's tool name")


def change_tool(config: Config, tool: str | None, *, cell: Any = None, out: Callable[[str], None] = print,
                mount: Callable[[Any], None] | None = None) -> ToolChangeResult:
    """Handle one tool change (see the module docstring)."""
    from payload_agent.session.verify import VerifyOptions, verify_tool

    name = resolve_tool(config, tool)
    db = library.tool_library_path(RobotState.for_config(config).root)
    if name is not None and library.get(db, config.robot.name, name) is not None:
        try:
            v = verify_tool(config, VerifyOptions(tool=name, unattended=True, apply=True, cell=cell, out=out,
                                                  mount=mount))
        except ToolMismatchError as exc:
            out(f"Tool {name!r} does not match its library entry: identifying it in full")
            return _identify(config, name, "identified-mismatch", cell, out, (str(exc.run_dir),), mount)
        applied = v.applied is not None or bool(v.setting_matches)
        return ToolChangeResult(name, "verified", v.robot_time_s, v.expected.mass_kg, v.expected.cog_mm, applied,
                                (str(v.run_dir),), f"verified in {v.robot_time_s:.1f} s of robot time"
                                + ("; payload written and read back" if v.applied is not None else
                                   "; the controller already held it" if v.setting_matches else
                                   "; the controller's payload setting could not be read"))
    return _identify(config, name, "identified-new" if name else "identified-unnamed", cell, out, (), mount)


def _identify(config: Config, name: str | None, action: str, cell, out, earlier: tuple[str, ...],
              mount) -> ToolChangeResult:
    from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

    # the arm goes back where the change found it (the last verify's start, or where the cell left it): the next
    # known-tool change then starts near its verify motion, not ~180° of wrist away at the inertia part's end
    outcome = run_identification(config, RunOptions(unattended=True, apply=True, tool=name, return_to_start=True),
                                         OperatorUI(out=out, progress=False),
                                         SimulatedCellUse(cell=cell, on_cell=mount))
    est = outcome.result.primary if outcome.result is not None else None
    return ToolChangeResult(name, action, None, None if est is None else float(est.mass_kg),
                            None if est is None else tuple(float(c) for c in est.cog_mm),  # type: ignore[arg-type]
                            outcome.applied is not None, (*earlier, str(outcome.run_dir)),
                            "identified in full" + (f" and stored as tool {name!r}" if name else "")
                            + ("; payload written and read back" if outcome.applied is not None else ""))
