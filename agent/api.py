"""The Python API: what cell software calls instead of a subprocess.

    import payload_agent
    result = payload_agent.identify("ec66", unattended=True, apply=False)
    print(result.primary.mass_kg, result.primary.cog_mm)

``identify`` does what ``payload-agent run`` does (find the robot YAML, check everything
before connecting, run the session through the safety gate, analyse, optionally write the
result to the controller) and returns the result dataclass. Errors are the project's
exception hierarchy (``payload_agent.errors``), each with its documented ``exit_code``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from payload_agent.configuration.config import Config, load_config
from payload_agent.configuration.paths import find_robot
from payload_agent.session.preflight import preflight
from payload_agent.session.runner import OperatorUI, RunOptions, run_identification
from payload_agent.solvers.results import RunResult


def identify(robot: str | Path | Config, *, unattended: bool = True, apply: bool = False, tool: str | None = None,
             solver: str | None = None, fresh_baseline: bool = False,
             out: Callable[[str], None] | None = None) -> RunResult:
    """Identify the mounted tool's mass and centre of mass; returns the result (see ``solvers.results``).

    ``robot`` is a robot YAML path, a name found on the robot search path, or a loaded Config.
    Unattended by default: it never prompts and fails where a person would be asked (for
    instance when no stored empty-flange baseline fits). ``apply`` writes the result to the
    controller only when every quality check passed, then reads it back.
    """
    config = robot if isinstance(robot, Config) else load_config(find_robot(robot))
    options = RunOptions(unattended=unattended, assume_yes=not unattended, apply=apply, tool=tool, solver=solver,
                         fresh_baseline=fresh_baseline)
    return run_identification(config, options, OperatorUI(out=out or (lambda _text: None), progress=False)).result


def verify(robot: str | Path | Config, tool: str | None = None, *, apply: bool = False,
           out: Callable[[str], None] | None = None):
    """`payload-agent verify`: seconds of motion testing whether the mounted tool is ``tool`` (a library name;
    None: the controller's current payload setting). Returns the ``session.verify.VerifyOutcome``; raises
    ``ToolMismatchError`` (exit code 7) when it is not, naming what differs."""
    from payload_agent.session.verify import VerifyOptions, verify_tool

    config = robot if isinstance(robot, Config) else load_config(find_robot(robot))
    preflight(config, calibration=True, apply=apply).require()
    return verify_tool(config, VerifyOptions(tool=tool, unattended=True, apply=apply,
                                             out=out or (lambda _text: None)))


def tool_changed(robot: str | Path | Config, tool: str | None, *, out: Callable[[str], None] | None = None):
    """A tool change named by the cell (a library name or tool number): a known tool is verified and its stored
    payload written; a new or mismatching one is identified, written and stored. Returns a
    ``session.tool_change.ToolChangeResult``."""
    from payload_agent.session.tool_change import change_tool

    config = robot if isinstance(robot, Config) else load_config(find_robot(robot))
    preflight(config, calibration=True, apply=True).require()
    return change_tool(config, tool, out=out or (lambda _text: None))
