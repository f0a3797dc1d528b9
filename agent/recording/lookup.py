"""Which run folder a command-line name means, and what a recorded run says it was solved with.

``solve`` and ``report`` take RUN_DIR as a path or as a run's name (the folder name `history`
shows, e.g. ``20261125-031500-sim-ec66``). A name is looked up in the runs folder of the robot
given with ``--robot`` and in every robot's ``runs/`` under the state home
(``$XDG_STATE_HOME/payload-agent/*/runs``); a miss names every folder searched, and a name
found twice names both, so the wrong run is never picked silently.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

from payload_agent.configuration.paths import state_home
from payload_agent.errors import ConfigError

MANIFEST = "manifest.json"


def runs_folders(extra: Iterable[Path] = ()) -> list[Path]:
    """Where run names are looked up: ``extra`` first (the --robot's runs folder), then every robot's ``runs/``."""
    folders = [Path(p) for p in extra]
    home = state_home()
    if home.is_dir():
        folders += sorted(d / "runs" for d in home.iterdir() if (d / "runs").is_dir())
    unique: list[Path] = []
    for f in folders:
        if f.resolve() not in {u.resolve() for u in unique}:
            unique.append(f)
    return unique


def find_run_dir(value: str, what: str, extra_runs_folders: Iterable[Path] = ()) -> Path:
    """The run folder ``value`` (a path, or a run's name) names; a ConfigError under ``what`` otherwise."""
    path = Path(os.path.expanduser(value))
    if path.is_dir():
        return _checked(path, what)
    if path.exists():
        raise ConfigError(what, f"{path} is a file, not a run folder")
    if os.sep in value or (os.altsep and os.altsep in value):
        raise ConfigError(what, f"no such run folder: {path}")
    folders = runs_folders(extra_runs_folders)
    matches = [f / value for f in folders if (f / value).is_dir()]
    if len(matches) > 1:
        raise ConfigError(what, f"the run name {value!r} is in more than one runs folder: "
                                + ", ".join(str(m) for m in matches) + " (give the path)")
    if not matches:
        where = ", ".join(str(f) for f in folders) or f"no runs folders under {state_home()} yet"
        raise ConfigError(what, f"no run folder {value!r} here or in: {where} "
                                "(`payload-agent history --robot NAME` lists a robot's runs)")
    return _checked(matches[0], what)


def _checked(path: Path, what: str) -> Path:
    if not (path / MANIFEST).is_file():
        raise ConfigError(what, f"{path} is not a run folder: it has no {MANIFEST}")
    return path


def recorded_solver(run_dir: Path, manifest: Mapping[str, Any]) -> str | None:
    """The solver the run itself used: the manifest's ``solver`` (runs since it was recorded), else the
    solver in the run's ``result.json``, else None (then the config's ``procedure.solver`` applies)."""
    solver = manifest.get("solver")
    if solver in ("general", "three-step"):
        return str(solver)
    try:
        data = json.loads((Path(run_dir) / "result.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    solver = data.get("solver") if isinstance(data, dict) else None
    return str(solver) if solver in ("general", "three-step") else None
