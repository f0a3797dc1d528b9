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
``NAME.yml``; ``--robot NAME.yaml`` as that file name) in, in this order: ``./configs``,
``$XDG_CONFIG_HOME/payload-agent/robots`` (default ``~/.config/payload-agent/robots``), every
folder in ``PAYLOAD_AGENT_ROBOTS`` (separated by ``os.pathsep``), then the robot files shipped
with the package (``payload_agent/configs`` when installed from a wheel, the project's
``configs/`` beside the package in a source checkout or editable install), so ``--robot
sim-ec66`` works from any directory. The first match wins; a miss lists every place looked.
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


def shipped_robot_dirs() -> list[Path]:
    """The folders holding the robot YAMLs shipped with the package, where they exist.

    A wheel installs them as package data in ``payload_agent/configs``; a source checkout or an
    editable install has them in ``configs/`` beside the package folder (``agent/``).
    """
    package = Path(__file__).resolve().parents[1]  # payload_agent (agent/ in a checkout)
    dirs = [package / "configs", package.parent / "configs"]
    return [d for d in dirs if (d / "sim-ec66.yaml").is_file()][:1]


def robot_search_path() -> list[Path]:
    """The folders ``--robot NAME`` searches, in order."""
    dirs = [Path.cwd() / "configs", config_home() / "robots"]
    dirs += [Path(p) for p in os.environ.get(ROBOTS_ENV, "").split(os.pathsep) if p.strip()]
    dirs += [d for d in shipped_robot_dirs() if d.resolve() not in {x.resolve() for x in dirs}]
    return dirs


def resolve_against(value: str | Path, base_dir: Path | None) -> Path:
    """A path from a YAML file: ``~`` expanded, relative ones taken from the YAML's folder."""
    p = Path(os.path.expanduser(str(value)))
    if p.is_absolute() or base_dir is None:
        return p
    return Path(base_dir) / p


def find_robot(name: str | Path) -> Path:
    """The robot YAML for ``--robot``: an existing file as given, else on the search path.

    ``NAME`` is looked up as ``NAME.yaml`` / ``NAME.yml``; a bare file name ending in ``.yaml`` or
    ``.yml`` that is not in the current directory is looked up as that name. A folder, or a miss,
    is a ConfigError naming every place looked.
    """
    text = str(name)
    given = Path(os.path.expanduser(text))
    if given.is_file():
        return given
    if given.is_dir():
        raise ConfigError("--robot", f"{str(given)!r} is a folder, not a robot YAML file (give the YAML file in it, "
                                     "e.g. configs/sim-ec66.yaml, or a robot NAME)")
    has_separator = os.sep in text or bool(os.altsep and os.altsep in text)
    if has_separator:
        raise ConfigError("--robot", f"no such file {str(given)!r}")
    names = [text] if given.suffix in (".yaml", ".yml") else [f"{text}.yaml", f"{text}.yml"]
    looked = [str(given.absolute())] if given.suffix in (".yaml", ".yml") else []
    for d in robot_search_path():
        for file_name in names:
            candidate = d / file_name
            if candidate.is_file():
                return candidate
        looked.append(str(d / names[0]))
    raise ConfigError("--robot", f"no robot file {names[0]!r} found; looked in: " + ", ".join(looked)
                      + f" (set {ROBOTS_ENV} to add folders, or give the YAML's path)")
