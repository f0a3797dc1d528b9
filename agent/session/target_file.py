"""The procedure ``plan --target-std`` chose, one command away: a robot YAML in the state folder.

The chosen candidate differs from the robot's YAML only in the ``procedure`` section (procedure file,
sweep, travel and acceleration speeds, sweep range), so the file written is the robot's own YAML with
those keys replaced. Paths the original gives relative to its own folder (storage, watch trigger) or
to the working directory (a procedure file) are written absolute, so the copy means the same from the
state folder. The robot's name is kept: the copy shares the state (baseline, calibration, history).
``payload-agent run --robot FILE`` runs it as planned; ``plan --robot FILE`` shows its moves.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

from payload_agent.configuration.config import Config
from payload_agent.recording.state import RobotState


def procedure_keys(config: Config, candidate) -> dict[str, Any]:
    """The ``procedure`` keys of the candidate (``evaluation.design.Candidate``), as the YAML spells them."""
    name = candidate.procedure or config.procedure.name
    path = Path(name)
    if path.suffix in (".yaml", ".yml") and path.exists():
        name = str(path.resolve())
    from payload_agent.evaluation.candidates import CONFIGURED

    keys = {"name": name, "speed_percent": float(candidate.speed_percent),
            "travel_speed_percent": float(candidate.travel_percent), "accel_percent": float(candidate.accel_percent),
            "sweep_deg": [float(candidate.sweep_from_deg), float(candidate.sweep_to_deg)]}
    if candidate.inertia != CONFIGURED:  # the stored baseline's plan: its inertia part as it recorded it
        keys["inertia"] = candidate.inertia or False
    return keys


def chosen_yaml(config: Config, candidate) -> dict[str, Any]:
    """The robot's YAML (as parsed) with the candidate's procedure keys and every relative path made absolute."""
    data = copy.deepcopy(dict(config.raw))
    data["procedure"] = {**dict(data.get("procedure") or {}), **procedure_keys(config, candidate)}
    storage = dict(data.get("storage") or {})
    for key, value in (("state_dir", config.storage.state_dir), ("runs_dir", config.storage.runs_dir)):
        if key in storage:
            storage[key] = str(Path(value).resolve())
    if storage:
        data["storage"] = storage
    trigger = (data.get("watch") or {}).get("trigger")
    if isinstance(trigger, dict) and "path" in trigger and config.watch is not None:
        path = config.watch.path
        if path is not None:
            data["watch"] = {**data["watch"], "trigger": {**trigger, "path": str(Path(path).resolve())}}
    return data


def target_file_path(config: Config, mass_std_g: float, cog_std_mm: float) -> Path:
    return RobotState.for_config(config).root / f"target-{mass_std_g:g}g-{cog_std_mm:g}mm.yaml"


def write_chosen(config: Config, candidate, mass_std_g: float, cog_std_mm: float, header: str) -> Path:
    """Write the chosen procedure as a robot YAML in the state folder (replacing an earlier one for the same
    target); ``header`` becomes its leading comment (what it was chosen for). Returns the path."""
    path = target_file_path(config, mass_std_g, cog_std_mm)
    path.parent.mkdir(parents=True, exist_ok=True)
    comment = "".join(f"# {line}\n" for line in header.splitlines())
    text = comment + yaml.safe_dump(chosen_yaml(config, candidate), sort_keys=False, allow_unicode=True)
    tmp = path.with_suffix(".yaml.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path
