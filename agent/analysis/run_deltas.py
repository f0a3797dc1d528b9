"""A run folder's loaded-minus-empty sweeps: read, segment, subtract, combine.

The one entry from a recorded run into the analysis; the pipeline (``analyse_run``) and the
drive-gain calibration both start here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from payload_agent.analysis.combine import add_combined
from payload_agent.analysis.delta import DeltaSweep, subtract_all
from payload_agent.errors import DataError
from payload_agent.recording.rundata import load_manifest, load_phase
from payload_agent.types import SweepKey


def deltas_for(run_dir: Path, gains: np.ndarray, baseline_dir: Path | None = None, *,
               combine: bool = True, notes: list[str] | None = None) -> dict[SweepKey, DeltaSweep]:
    """Loaded-minus-empty sweeps of a run; the empty phase comes from ``baseline_dir`` if given.

    With ``combine``, every sweep recorded in both directions also gets its friction-cancelling
    combined sweep (direction "both", see ``payload_agent.analysis.combine``); problems go to ``notes``.
    """
    manifest = load_manifest(run_dir)
    loaded = load_phase(run_dir, "loaded", gains, manifest)
    if not loaded:
        raise DataError(f"{run_dir}: no complete loaded sweep to analyse")
    empty_dir = Path(baseline_dir) if baseline_dir is not None else Path(run_dir)
    empty = load_phase(empty_dir, "empty", gains)
    deltas = subtract_all(loaded, empty)
    if combine:
        deltas, problems = add_combined(deltas)
        if notes is not None:
            notes.extend(problems)
    return deltas
