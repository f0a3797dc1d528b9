"""A run folder for a motion recorded by someone else (``payload-agent import``).

The folder holds everything its analysis reads, as every run folder does: the two recordings
exactly as given (copied, with their SHA-256), the column map that reads them, the robot's
config snapshot (its kinematics), the gains if the user chose them, and the result. ``solve``
on the folder repeats the analysis from these files alone (docs/run-format.md, "Imported
recordings").

```
RUN_DIR/
  manifest.json          kind "recorded-motion": sources, column map, gains choice, config snapshot
  recorded/empty.<ext>   the empty-flange recording, byte for byte
  recorded/loaded.<ext>  the loaded recording, byte for byte
  result.json            the analysis (result-solve-<time>.json for every later solve)
```
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from payload_agent.errors import DataError
from payload_agent.recording.rundata import SUPPORTED_FORMATS

KIND = "recorded-motion"
ROLES = ("empty", "loaded")


@dataclass(frozen=True)
class ImportedRun:
    run_dir: Path
    manifest: dict[str, Any]

    def recording(self, role: str) -> Path:
        return self.run_dir / self.manifest["recordings"][role]["file"]

    @property
    def column_map(self) -> str | None:
        return self.manifest.get("column_map")

    @property
    def gains(self) -> Mapping[str, Any] | None:
        return self.manifest.get("gains")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 16), b""):
            h.update(block)
    return h.hexdigest()


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


def create_imported_run(runs_dir: Path, robot_name: str, config_snapshot: Mapping[str, Any], sources: Mapping[str, Path],
                        column_map: str | None, gains: Mapping[str, Any] | None) -> ImportedRun:
    """Make the folder and copy the recordings in; nothing is analysed yet."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run_dir = runs_dir / f"{stamp}-{robot_name}-imported"
    n = 1
    while run_dir.exists():
        n += 1
        run_dir = runs_dir / f"{stamp}-{robot_name}-imported-{n}"
    (run_dir / "recorded").mkdir(parents=True)
    recordings = {}
    for role in ROLES:
        src = Path(sources[role])
        dest = run_dir / "recorded" / f"{role}{src.suffix or '.csv'}"
        shutil.copyfile(src, dest)
        recordings[role] = {"file": str(dest.relative_to(run_dir)), "source": str(src.resolve()),
                            "sha256": _sha256(dest), "bytes": dest.stat().st_size}
    manifest = {"format": SUPPORTED_FORMATS[-1], "kind": KIND, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "robot": robot_name, "config": dict(config_snapshot), "recordings": recordings,
                "column_map": column_map, "gains": dict(gains) if gains else None}
    _write_json(run_dir / "manifest.json", manifest)
    return ImportedRun(run_dir, manifest)


def is_imported(manifest: Mapping[str, Any]) -> bool:
    return manifest.get("kind") == KIND


def open_imported_run(run_dir: Path, manifest: Mapping[str, Any]) -> ImportedRun:
    """The folder's recordings, checked against the hashes taken when they were copied in."""
    where = run_dir / "manifest.json"
    recs = manifest.get("recordings")
    if not isinstance(recs, Mapping) or any(not isinstance(recs.get(r), Mapping) for r in ROLES):
        raise DataError(f"{where}: recordings.empty and recordings.loaded are needed in an imported run")
    run = ImportedRun(run_dir, dict(manifest))
    for role in ROLES:
        path = run.recording(role)
        if not path.is_file():
            raise DataError(f"{where}: recordings.{role}: {path} is missing")
        if recs[role].get("sha256") and _sha256(path) != recs[role]["sha256"]:
            raise DataError(f"{path} changed since it was imported (SHA-256 differs from the manifest's)")
    return run


def write_result(run_dir: Path, result: Mapping[str, Any], name: str = "result.json") -> Path:
    path = run_dir / name
    if path.exists():
        raise DataError(f"{path} exists; results are never overwritten")
    _write_json(path, result)
    return path
