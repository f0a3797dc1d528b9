"""Where payload-agent keeps what outlives one run, per robot.

``<storage.state_dir>/<robot.name>/`` (default ``$XDG_STATE_HOME/payload-agent/<robot>/``,
see ``payload_agent.configuration.paths``) holds:

- ``gains.json``: the drive-gain calibration written by ``payload-agent calibrate``;
- ``baseline/``: the stored empty-flange run (a run folder) plus ``baseline/baseline.json``
  describing what it depends on (written by ``payload-agent baseline``);
- ``history.sqlite``: every identification, applied or not (``payload-agent history``);
- ``runs/``: the run folders, unless ``storage.runs_dir`` puts them elsewhere.

One folder per robot name, so two robots sharing a state folder never mix.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from payload_agent.configuration.config import Config


@dataclass(frozen=True)
class RobotState:
    root: Path

    @classmethod
    def for_config(cls, config: Config) -> "RobotState":
        return cls(Path(config.storage.state_dir) / config.robot.name)

    @property
    def gains_path(self) -> Path:
        return self.root / "gains.json"

    @property
    def baseline_dir(self) -> Path:
        return self.root / "baseline"

    @property
    def baseline_info_path(self) -> Path:
        return self.baseline_dir / "baseline.json"

    @property
    def history_db(self) -> Path:
        return self.root / "history.sqlite"

    @property
    def simulated_sessions_path(self) -> Path:
        """How many times a simulated controller was started for this robot (``session.simulation``)."""
        return self.root / "simulated-sessions"

    def ensure(self) -> "RobotState":
        self.root.mkdir(parents=True, exist_ok=True)
        return self


def describe_locations(config: Config, run_dir: Path | None = None) -> str:
    """The line every session prints: where this robot's state is and where the run folder goes."""
    state = RobotState.for_config(config)
    where = f"State of robot {config.robot.name!r}: {state.root.absolute()} (baseline, drive-gain calibration, history)"
    if run_dir is not None:
        return where + f"\nRun folder: {Path(run_dir).absolute()}"
    return where + f"\nRun folders go to: {Path(config.storage.runs_dir).absolute()}"


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON so that a crash never leaves a half-written state file behind."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=2, sort_keys=True)
            fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
