"""A run folder's sweeps as the analysis reads them: each phase's sweeps and the plan's windows.

The one entry from a recorded run into the analysis; the pipeline (``analyse_run``, which hands
``phases_for``'s sweeps to the pure ``evaluation.analyse``) and the drive-gain calibration both start here. The constant-speed windows come from the plan on file
(``manifest.json`` ``plan``: each sweep's start is the previous move's target), the same
commands for the empty and the loaded phase. ``check_segmentation`` is the test a baseline
must pass before it is stored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from payload_agent.analysis.delta import window_of
from payload_agent.analysis.segmenter import SweepCommand, Window, sweep_commands
from payload_agent.errors import DataError
from payload_agent.recording.rundata import SweepData, load_manifest, load_phase
from payload_agent.types import SweepKey


def commands_of(manifest: dict[str, Any], where: str = "run") -> dict[SweepKey, SweepCommand]:
    """Each sweep's commanded PTP move from a manifest's ``plan`` (empty if the manifest has none)."""
    plan = manifest.get("plan")
    if not plan:
        return {}
    try:
        return sweep_commands(plan)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise DataError(f"{where}: manifest.json: cannot read the plan ({type(exc).__name__}: {exc})") from None


def phases_for(run_dir: Path, gains: np.ndarray, baseline_dir: Path | None = None, *,
               notes: list[str] | None = None
               ) -> tuple[dict[SweepKey, SweepData], dict[SweepKey, SweepData], dict[SweepKey, SweepCommand]]:
    """(loaded sweeps, empty sweeps, the plan's sweep commands) of a run, effort in N·m with ``gains``.

    The empty phase comes from ``baseline_dir`` if given. The raw sweeps, before any subtraction:
    what ``evaluation.systematics`` compensates (joint elasticity) and measures (friction) on.
    """
    manifest = load_manifest(run_dir)
    loaded = load_phase(run_dir, "loaded", gains, manifest)
    if not loaded:
        raise DataError(f"{run_dir}: no complete loaded sweep to analyse")
    empty_dir = Path(baseline_dir) if baseline_dir is not None else Path(run_dir)
    empty = load_phase(empty_dir, "empty", gains)
    commands = commands_of(manifest, str(run_dir))
    if notes is not None and not commands:
        notes.append("the manifest has no plan: constant-speed windows found in the data alone")
    return loaded, empty, commands


def check_segmentation(run_dir: Path, phase: str = "empty") -> dict[str, Window]:
    """Segment every complete sweep of one phase of a run folder with its plan; raise if any fails.

    For the session before it stores a baseline: a baseline whose own sweeps cannot be
    segmented would fail every later run. Returns the verified window of every sweep by name.
    Raises DataError listing every sweep that failed (and if the phase has no complete sweep or
    a planned sweep is missing from it).
    """
    windows, failed = segment_phase(run_dir, phase)
    if failed:
        raise DataError(f"{run_dir}: the {phase} phase cannot be segmented:\n  - " + "\n  - ".join(failed.values()))
    return windows


def segment_phase(run_dir: Path, phase: str) -> tuple[dict[str, Window], dict[str, str]]:
    """(verified window by sweep name, problem by sweep name) for one phase of a run folder; a planned
    sweep not recorded complete is a problem too. The session checks the empty run with this right after
    recording it, so a bad sweep is redone before the tool is mounted."""
    run_dir = Path(run_dir)
    manifest = load_manifest(run_dir)
    sweeps = load_phase(run_dir, phase, np.ones(6), manifest)  # angles only: the gains do not matter
    commands = commands_of(manifest, str(run_dir))
    if not sweeps and not commands:
        raise DataError(f"{run_dir}: the {phase!r} phase has no complete sweep")
    failed = {k.name: f"{k.name}: planned but not recorded complete" for k in commands if k not in sweeps}
    windows: dict[str, Window] = {}
    for key, sweep in sweeps.items():
        try:
            windows[key.name] = window_of(sweep, commands.get(key))
        except DataError as exc:
            failed[key.name] = str(exc)
    return windows, failed
