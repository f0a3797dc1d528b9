"""Which empty-flange run a run folder's analysis subtracts: the one identity a calibration and a tool run compare.

Why: the drive-gain calibration and a later tool run usually subtract the SAME empty run (both reuse the robot's
stored baseline, or the calibration recorded the empty run that became it); the baseline's noise is then in both
and partly cancels in the tool's mass (``evaluation.shared_baseline``). A run folder's empty phase is either its
own recording (the folder is then the baseline's source, as ``session.baseline`` stores it) or a copy of the stored
baseline, whose manifest entry names the run it came from (``phases.empty.from_baseline.source_run``).
"""

from __future__ import annotations

from pathlib import Path

from payload_agent.errors import DataError
from payload_agent.recording.rundata import load_manifest


def empty_run_source(run_dir: Path, baseline_dir: Path | None = None) -> str | None:
    """The folder (resolved, as a string) whose empty-flange run the analysis of ``run_dir`` subtracts (from
    ``baseline_dir`` when given, as ``solve --baseline``); None when the manifest cannot tell (an unreadable one,
    or an empty phase without its origin)."""
    folder = Path(baseline_dir) if baseline_dir is not None else Path(run_dir)
    try:
        manifest = load_manifest(folder)
    except DataError:
        return None
    empty = (manifest.get("phases") or {}).get("empty")
    if not isinstance(empty, dict):
        return None
    origin = empty.get("from_baseline")
    if origin is None:
        return str(folder.resolve())
    source = origin.get("source_run") if isinstance(origin, dict) else None
    return str(Path(source).resolve()) if isinstance(source, str) and source not in ("", ".") else None


def same_baseline(calibration_source: str | None, run_source: str | None) -> bool:
    """True when both are known and name the same empty run."""
    return calibration_source is not None and run_source is not None and calibration_source == run_source


__all__ = ["empty_run_source", "same_baseline"]
