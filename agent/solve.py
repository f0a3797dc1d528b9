"""``payload-agent solve``: analyse a recorded run folder again, from the folder alone, into a new file.

- Nothing outside the run folder is read: the config is the manifest's snapshot (or ``--robot``
  for the kinematics), the drive gains are the run's own (``RUN_DIR/calibration.json`` when the
  run was recorded with a calibration, else the manifest's ``gains_nm_per_unit`` for its
  ``effort_unit``), never a calibration of the current directory or of the user's state.
- Nothing is overwritten: the result goes to a new file (``result-solve-<time>.json``, or
  ``--result PATH`` if that does not exist yet) that says which baseline, solver and gains it
  used (key ``solve``). ``result.json`` and the history are left alone unless asked
  (``--history``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from payload_agent.version import __version__
from payload_agent.configuration.config import Config
from payload_agent.configuration.recorded import recorded_effort
from payload_agent.errors import ConfigError, DataError
from payload_agent.recording.rundata import check_manifest, load_manifest
from payload_agent.evaluation.calibration import RUN_CALIBRATION
from payload_agent.solvers.results import RunResult, format_table



@dataclass
class Solved:
    result: RunResult
    path: Path
    table: str
    baseline_text: str
    gains_text: str
    baseline_dir: Path | None

    def record_history(self, config: Config, tool: str | None) -> int:
        from payload_agent.recording import history
        from payload_agent.recording.state import RobotState

        entry = history.HistoryEntry.from_result_json(
            self.result.to_json(), tool=tool,
            baseline_run_dir=None if self.baseline_dir is None else str(self.baseline_dir),
            gains_note=self.gains_text, config_fingerprint=config.fingerprint("robot", "effort", "procedure"))
        return history.record(RobotState.for_config(config).ensure().history_db, entry)


def run_gains(run_dir: Path, manifest: dict[str, Any]) -> tuple[np.ndarray | None, str]:
    """The run's nominal gains (None when it was recorded with a calibration, which the analysis reads from the
    folder itself) and a sentence saying where the gains come from."""
    from payload_agent.evaluation.calibration import run_calibration

    source = str(run_dir / "manifest.json")
    effort = recorded_effort(manifest, manifest.get("config") or {}, source)
    cal = run_calibration(run_dir)
    if cal is not None:
        if cal.effort_unit != effort.unit:
            raise DataError(f"{run_dir / RUN_CALIBRATION}: calibrated for effort unit {cal.effort_unit!r}, the run "
                            f"recorded {effort.unit!r}")
        joints = ", ".join(str(j + 1) for j in cal.fitted_joints)
        return None, (f"the calibration recorded with the run ({RUN_CALIBRATION} of {cal.created_utc[:10]}, joints "
                      f"{joints} fitted; effort in {effort.unit})")
    return (np.asarray(effort.gains_nm_per_unit, float),
            f"the run's gains_nm_per_unit {list(effort.gains_nm_per_unit)} (effort in {effort.unit}; nominal, "
            "their error is not in the reported uncertainty)")


def new_result_path(run_dir: Path, given: Path | None) -> Path:
    if given is not None:
        if given.exists():
            raise ConfigError("--result", f"{given} exists; solve never overwrites a result: choose another path "
                                          "or move the old file away")
        return given
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    path, n = run_dir / f"result-solve-{stamp}.json", 1
    while path.exists():
        n += 1
        path = run_dir / f"result-solve-{stamp}-{n}.json"
    return path


def solve_run(run_dir: Path, manifest: dict[str, Any], config: Config, *, solver: str | None = None,
              baseline_dir: Path | None = None, result_path: Path | None = None) -> Solved:
    from payload_agent.evaluation.pipeline import analyse_run

    run_dir = Path(run_dir)
    path = new_result_path(run_dir, result_path)  # refuse before the work, not after
    gains, gains_text = run_gains(run_dir, manifest)
    if baseline_dir is not None:
        other = load_manifest(baseline_dir)
        check_manifest(other, str(baseline_dir / "manifest.json"), phases=("empty",))
        if (other.get("phases") or {}).get("empty") is None:
            raise DataError(f"{baseline_dir}: has no empty-flange phase to use as the baseline")
        if other.get("effort_unit") != manifest.get("effort_unit"):
            raise DataError(f"{baseline_dir} recorded effort in {other.get('effort_unit')!r}, {run_dir} in "
                            f"{manifest.get('effort_unit')!r}: they cannot be subtracted")
        baseline_text = f"the empty phase of {baseline_dir} (recorded {other.get('created_utc', '?')})"
    else:
        empty = (manifest.get("phases") or {}).get("empty") or {}
        origin = empty.get("from_baseline") if isinstance(empty, dict) else None
        baseline_text = "the run's own empty phase" + (
            f" (copied from the stored baseline {origin.get('dir', '?')} of {origin.get('recorded_utc', '?')})"
            if isinstance(origin, dict) else "")
    result = analyse_run(config, run_dir, solver, baseline_dir, gains=gains)
    if gains is not None and result.extra["gains_source"] == "given by the caller":  # not the controller's fit
        result.extra["gains_source"] = gains_text
    result.extra["solve"] = {
        "solved_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"), "software_version": __version__,
        "baseline_dir": None if baseline_dir is None else str(baseline_dir), "baseline": baseline_text,
        "solver": result.primary.solver, "gains_nm_per_unit": result.extra["gains_nm_per_unit"],
        "gains_source": gains_text,
        "config": config.source}
    with open(path, "x", encoding="utf-8") as fh:  # exclusive: never replaces a file
        json.dump(result.to_json(), fh, indent=2)
    return Solved(result, path, format_table(result, manifest.get("simulation_truth")), baseline_text, gains_text,
                  baseline_dir)
