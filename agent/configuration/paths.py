"""Where robot YAMLs are found and where per-robot state lives, independent of the shell's directory.

State (stored baseline, drive-gain calibration, history, and the run folders) follows the
robot, not the current directory: a cron job started in ``/`` must find the same baseline
as the operator who recorded it from a project folder. The default is the XDG base
directory specification's state home:

    $XDG_STATE_HOME/payload-agent/<robot.name>/          (default ~/.local/state/...)
        baseline/  gains.json  history.sqlite  runs/<run folders>

Runs live *below* the robot's state folder so that one folder holds everything about a
robot and can be copied or backed up as a whole. ``storage.state_dir`` / ``storage.runs_dir``
in the YAML override this; relative paths there are resolved against the YAML's own folder.

``--robot NAME`` (no path separator, no such file) is looked up as ``NAME.yaml`` (or
``NAME.yml``) in, in this order: ``./configs``, ``$XDG_CONFIG_HOME/payload-agent/robots``
(default ``~/.config/payload-agent/robots``), then every folder in ``PAYLOAD_AGENT_ROBOTS``
(separated by ``os.pathsep``). The first match wins.
"""

from __future__ import annotations

import os
from pathlib import Path

from payload_agent.errors import ConfigError

APP = "payload-agent"
ROBOTS_ENV = "PAYLOAD_AGENT_ROBOTS"


def _xdg(var: str, fallback: str) -> Path:
    value = os.environ.get(var, "")
    # the spec: a relative path in these variables is invalid and must be ignored
    if value and os.path.isabs(value):
        return Path(value)
    return Path.home() / fallback


def state_home() -> Path:
    """``$XDG_STATE_HOME/payload-agent`` (default ``~/.local/state/payload-agent``)."""
    return _xdg("XDG_STATE_HOME", ".local/state") / APP


def config_home() -> Path:
    """``$XDG_CONFIG_HOME/payload-agent`` (default ``~/.config/payload-agent``)."""
    return _xdg("XDG_CONFIG_HOME", ".config") / APP


def robot_search_path() -> list[Path]:
    """The folders ``--robot NAME`` searches, in order."""
    dirs = [Path.cwd() / "configs", config_home() / "robots"]
    dirs += [Path(p) for p in os.environ.get(ROBOTS_ENV, "").split(os.pathsep) if p.strip()]
    return dirs


def resolve_against(value: str | Path, base_dir: Path | None) -> Path:
    """A path from a YAML file: ``~`` expanded, relative ones taken from the YAML's folder."""
    p = Path(os.path.expanduser(str(value)))
    if p.is_absolute() or base_dir is None:
        return p
    return Path(base_dir) / p


def find_robot(name: str | Path) -> Path:
    """The robot YAML for ``--robot``: an existing file as given, else ``NAME.yaml`` on the search path."""
    given = Path(os.path.expanduser(str(name)))
    if given.is_file():
        return given
    text = str(name)
    looks_like_path = os.sep in text or (os.altsep and os.altsep in text) or given.suffix in (".yaml", ".yml")
    if not looks_like_path:
        for d in robot_search_path():
            for suffix in (".yaml", ".yml"):
                candidate = d / f"{text}{suffix}"
                if candidate.is_file():
                    return candidate
    searched = "" if looks_like_path else (" and no " + f"{text}.yaml in " + ", ".join(str(d) for d in robot_search_path())
                                           + f" (set {ROBOTS_ENV} to add folders)")
    raise ConfigError("--robot", f"no such file {str(given)!r}{searched}")
