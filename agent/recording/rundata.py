"""Reads run folders back: the manifest and each sweep's samples, effort converted to N·m.

Run folders may be written by other tools from docs/run-format.md alone, so reading is by
name, never by position: CSV columns are found by their header (any order; extra columns are
ignored), and the manifest keys the analysis needs are checked up front with errors that
name the key (``check_manifest``; docs/run-manifest.schema.json says the same in JSON Schema).
"""

from __future__ import annotations

import csv
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.errors import DataError
from payload_agent.types import SweepKey

N_JOINTS = 6
Q_COLUMNS = tuple(f"q{j}_rad" for j in range(1, N_JOINTS + 1))
EFFORT_COLUMNS = tuple(f"effort{j}" for j in range(1, N_JOINTS + 1))
TIME_COLUMNS = ("t_ctrl_s", "t_recv_s")  # at least one; t_ctrl_s is used when every row has it
FORMAT_FAMILY = "payload-agent-run/"
SUPPORTED_FORMATS = ("payload-agent-run/1",)
DIRECTIONS = ("up", "down")
PHASES = ("empty", "loaded")
# what the analysis reads; docs/run-format.md and the schema list the same
REQUIRED_MANIFEST_KEYS = ("format", "config", "effort_unit", "phases")
REQUIRED_SWEEP_KEYS = ("file", "pose", "joint", "direction", "speed_percent", "status")


@dataclass
class SweepData:
    key: SweepKey
    t: np.ndarray  # s (controller clock if available, else receive time)
    q: np.ndarray  # (n, 6) rad
    effort_nm: np.ndarray  # (n, 6) N·m
    source: str  # file path, for messages


def load_manifest(run_dir: Path) -> dict[str, Any]:
    path = Path(run_dir) / "manifest.json"
    if not Path(run_dir).is_dir():
        raise DataError(f"{run_dir} is not a folder")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{run_dir} is not a run folder: manifest.json is missing") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot parse the manifest ({exc})") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: the manifest must be a JSON object, got {type(data).__name__}")
    return data


def check_manifest(manifest: Mapping[str, Any], source: str, phases: Sequence[str] = PHASES) -> None:
    """DataError naming the first missing or malformed key the analysis needs (``phases``: those it reads)."""
    for key in REQUIRED_MANIFEST_KEYS:
        if key not in manifest:
            raise DataError(f"{source}: required key {key!r} is missing (docs/run-format.md lists the required keys)")
    fmt = manifest["format"]
    if not isinstance(fmt, str) or not fmt.startswith(FORMAT_FAMILY):
        raise DataError(f"{source}: format is {fmt!r}, expected {SUPPORTED_FORMATS[0]!r}")
    if fmt not in SUPPORTED_FORMATS:
        raise DataError(f"{source}: format {fmt!r} is newer than this payload-agent reads "
                        f"({', '.join(SUPPORTED_FORMATS)}); upgrade payload-agent")
    if not isinstance(manifest["config"], Mapping):
        raise DataError(f"{source}: config must be an object (the robot YAML as loaded)")
    if not isinstance(manifest["phases"], Mapping):
        raise DataError(f"{source}: phases must be an object with 'empty' and/or 'loaded'")
    for phase in phases:
        info = manifest["phases"].get(phase)
        if info is None:
            continue
        sweeps = info.get("sweeps") if isinstance(info, Mapping) else None
        if not isinstance(sweeps, list):
            raise DataError(f"{source}: phases.{phase}.sweeps must be a list")
        for i, entry in enumerate(sweeps):
            _check_sweep_entry(entry, f"phases.{phase}.sweeps[{i}]", source)


def _check_sweep_entry(entry: Any, where: str, source: str) -> SweepKey:
    if not isinstance(entry, Mapping):
        raise DataError(f"{source}: {where} must be an object")
    for key in REQUIRED_SWEEP_KEYS:
        if key not in entry:
            raise DataError(f"{source}: {where}.{key} is missing")
    if entry["direction"] not in DIRECTIONS:
        raise DataError(f"{source}: {where}.direction is {entry['direction']!r}; expected 'up' (link elevation "
                        "increasing) or 'down' — a sweep recorded both ways is two entries, one per file")
    try:
        joint = int(entry["joint"])
        speed = float(entry["speed_percent"])
    except (TypeError, ValueError):
        raise DataError(f"{source}: {where}: joint must be an integer and speed_percent a number") from None
    if joint != entry["joint"] or not 1 <= joint <= N_JOINTS:
        raise DataError(f"{source}: {where}.joint must be an integer 1..{N_JOINTS}, got {entry['joint']!r}")
    return SweepKey(str(entry["pose"]), joint, str(entry["direction"]), speed)


def read_sweep_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t s, q (n, 6) rad, effort (n, 6) in the manifest's unit) from one sweep CSV, columns by header name."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            header = next(csv.reader(fh), None)
    except OSError as exc:
        raise DataError(f"{path}: cannot read samples ({exc.strerror or exc})") from None
    if not header:
        raise DataError(f"{path}: empty file (expected a header line naming the columns)")
    names = [h.strip() for h in header]
    index: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in index and name in (*Q_COLUMNS, *EFFORT_COLUMNS, *TIME_COLUMNS):
            raise DataError(f"{path}: column {name!r} appears twice in the header")
        index.setdefault(name, i)
    missing = [c for c in (*Q_COLUMNS, *EFFORT_COLUMNS) if c not in index]
    times = [c for c in TIME_COLUMNS if c in index]
    if missing or not times:
        need = missing + ([] if times else ["t_ctrl_s or t_recv_s"])
        raise DataError(f"{path}: the header lacks {', '.join(need)} (it has {', '.join(names)}); "
                        "docs/run-format.md lists the columns")
    cols = [index[c] for c in (*times, *Q_COLUMNS, *EFFORT_COLUMNS)]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a torn last line of an aborted run is skipped, not fatal
            raw = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2, usecols=cols,
                                invalid_raise=False)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read samples ({exc})") from None
    if raw.size == 0:
        raise DataError(f"{path}: no samples below the header")
    nt = len(times)
    q, effort = raw[:, nt:nt + N_JOINTS], raw[:, nt + N_JOINTS:]
    bad = ~(np.isfinite(q).all(axis=1) & np.isfinite(effort).all(axis=1))
    if bad.any():
        raise DataError(f"{path}: {int(bad.sum())} row(s) have a missing or non-numeric angle or effort "
                        f"(first at data row {int(np.argmax(bad)) + 1})")
    t = None
    for k, name in enumerate(times):
        col = raw[:, k]
        if np.isfinite(col).all():
            t = col
            break
    if t is None:
        raise DataError(f"{path}: no time column is complete ({' and '.join(times)} have empty or non-numeric "
                        "cells); t_recv_s must be given on every row when t_ctrl_s is not")
    return t, q, effort


def load_phase(run_dir: Path, phase: str, gains_nm_per_unit: np.ndarray,
               manifest: dict[str, Any] | None = None, *,
               statuses: Sequence[str] = ("complete",)) -> dict[SweepKey, SweepData]:
    """Every sweep of one phase ("empty" or "loaded") whose status is in ``statuses`` (default: complete
    sweeps only, the ones the analysis may use), keyed by pose/joint/direction/speed."""
    run_dir = Path(run_dir)
    manifest = manifest or load_manifest(run_dir)
    source = str(run_dir / "manifest.json")
    info = (manifest.get("phases") or {}).get(phase)
    if info is None:
        raise DataError(f"{run_dir}: the run has no {phase!r} phase")
    sweeps = info.get("sweeps", []) if isinstance(info, Mapping) else None
    if not isinstance(sweeps, list):
        raise DataError(f"{source}: phases.{phase}.sweeps must be a list")
    gains = np.asarray(gains_nm_per_unit, float)
    out: dict[SweepKey, SweepData] = {}
    for i, entry in enumerate(sweeps):
        key = _check_sweep_entry(entry, f"phases.{phase}.sweeps[{i}]", source)
        if entry.get("status") not in statuses:
            continue
        path = run_dir / str(entry["file"])
        t, q, effort = read_sweep_csv(path)
        out[key] = SweepData(key, t, q, effort * gains, str(path))
    return out


@dataclass(frozen=True)
class WristRecord:
    """One wrist move of the inertia part in one phase (effort in N·m)."""

    name: str
    t: np.ndarray  # (n,) s
    q: np.ndarray  # (n, 6) rad
    effort_nm: np.ndarray  # (n, 6)


def load_wrist_moves(run_dir: Path, phase: str, gains_nm_per_unit: np.ndarray,
                     manifest: dict[str, Any] | None = None) -> dict[str, WristRecord]:
    """The complete wrist moves of one phase by name (empty for a run recorded without the inertia part)."""
    run_dir = Path(run_dir)
    manifest = manifest or load_manifest(run_dir)
    source = str(run_dir / "manifest.json")
    info = (manifest.get("phases") or {}).get(phase) or {}
    entries = info.get("wrist_moves", []) if isinstance(info, Mapping) else []
    if not isinstance(entries, list):
        raise DataError(f"{source}: phases.{phase}.wrist_moves must be a list")
    out: dict[str, WristRecord] = {}
    for i, entry in enumerate(entries):
        if not isinstance(entry, Mapping) or not isinstance(entry.get("name"), str) or "file" not in entry:
            raise DataError(f"{source}: phases.{phase}.wrist_moves[{i}] needs a name and a file")
        if entry.get("status") != "complete":
            continue
        t, q, effort = read_sweep_csv(run_dir / str(entry["file"]))
        out[entry["name"]] = WristRecord(entry["name"], t, q, effort * np.asarray(gains_nm_per_unit, float))
    return out


MOUNT_KEY = "start_joint_angles_rad"  # the loaded phase's first start, where the tool went on (session.phases)


def mount_angles(run_dir: Path, manifest: dict[str, Any] | None = None) -> np.ndarray | None:
    """The joint angles (rad) the loaded phase first started from, where the tool was mounted (the rest of a tool
    cable, ``systematics.cable_spring``); None for a run recorded without them (older runs, other tools)."""
    manifest = manifest or load_manifest(Path(run_dir))
    info = (manifest.get("phases") or {}).get("loaded") or {}
    value = info.get(MOUNT_KEY) if isinstance(info, Mapping) else None
    if value is None:
        return None
    q = np.asarray(value, float) if isinstance(value, list) and all(isinstance(v, (int, float)) for v in value) else None
    if q is None or q.shape != (6,) or not np.all(np.isfinite(q)):
        raise DataError(f"{Path(run_dir) / 'manifest.json'}: phases.loaded.{MOUNT_KEY} must be 6 joint angles in "
                        f"rad, got {value!r}")
    return q

