"""Everything after the recorder: segment, subtract the baseline, solve. Offline-safe.

``payload-agent solve RUN_DIR`` and ``run`` both come through here, so a recorded
run can always be re-analysed and gives the same answer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from payload_agent.delta import DeltaSweep, subtract_all
from payload_agent.errors import DataError
from payload_agent.kinematics import Kinematics
from payload_agent.planner import SweepKey
from payload_agent.results import Estimate
from payload_agent.rundata import load_manifest, load_phase
from payload_agent.solvers import SOLVERS


def deltas_for(run_dir: Path, gains: np.ndarray, baseline_dir: Path | None = None) -> dict[SweepKey, DeltaSweep]:
    """Loaded-minus-empty sweeps of a run; the empty phase comes from ``baseline_dir`` if given."""
    manifest = load_manifest(run_dir)
    loaded = load_phase(run_dir, "loaded", gains, manifest)
    if not loaded:
        raise DataError(f"{run_dir}: no complete loaded sweep to analyse")
    empty_dir = Path(baseline_dir) if baseline_dir is not None else Path(run_dir)
    empty = load_phase(empty_dir, "empty", gains)
    return subtract_all(loaded, empty)


def solve_all(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: str) -> tuple[Estimate, list[Estimate]]:
    """The primary solver's estimate, plus every other solver's that can be computed on the same data."""
    if primary not in SOLVERS:
        raise DataError(f"unknown solver {primary!r}; available: {', '.join(SOLVERS)}")
    main = SOLVERS[primary](deltas, kin)
    others = []
    for name, fn in SOLVERS.items():
        if name == primary:
            continue
        try:
            others.append(fn(deltas, kin))
        except DataError as exc:
            main.notes.append(f"{name} not computed: {exc}")
    return main, others
