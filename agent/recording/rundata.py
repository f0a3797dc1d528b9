"""Reads run folders back: the manifest and each sweep's samples, effort converted to N·m."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from payload_agent.errors import DataError
from payload_agent.types import SweepKey


@dataclass
class SweepData:
    key: SweepKey
    t: np.ndarray  # s (controller clock if available, else receive time)
    q: np.ndarray  # (n, 6) rad
    effort_nm: np.ndarray  # (n, 6) N·m
    source: str  # file path, for messages


def load_manifest(run_dir: Path) -> dict[str, Any]:
    path = Path(run_dir) / "manifest.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{run_dir} is not a run folder: manifest.json is missing") from None
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: cannot parse the manifest ({exc})") from None


def load_phase(run_dir: Path, phase: str, gains_nm_per_unit: np.ndarray,
               manifest: dict[str, Any] | None = None) -> dict[SweepKey, SweepData]:
    """Every complete sweep of one phase ("empty" or "loaded"), keyed by pose/joint/direction/speed."""
    run_dir = Path(run_dir)
    manifest = manifest or load_manifest(run_dir)
    info = manifest.get("phases", {}).get(phase)
    if info is None:
        raise DataError(f"{run_dir}: the run has no {phase!r} phase")
    out: dict[SweepKey, SweepData] = {}
    for entry in info.get("sweeps", []):
        if entry.get("status") != "complete":
            continue
        key = SweepKey(entry["pose"], int(entry["joint"]), entry["direction"], float(entry["speed_percent"]))
        path = run_dir / entry["file"]
        try:
            raw = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2)
        except (OSError, ValueError) as exc:
            raise DataError(f"{path}: cannot read samples ({exc})") from None
        if raw.size == 0 or raw.shape[1] != 14:
            raise DataError(f"{path}: expected 14 columns of samples, got shape {raw.shape}")
        t = raw[:, 0] if not np.isnan(raw[:, 0]).any() else raw[:, 1]
        out[key] = SweepData(key, t, raw[:, 2:8], raw[:, 8:14] * np.asarray(gains_nm_per_unit), str(path))
    return out
