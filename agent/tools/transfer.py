"""Tool library export and import as JSON, so a second cell with the same tools can start from it.

The document (``FORMAT``)::

    {"format": "payload-agent-tools/2", "robot": "ec66", "exported_utc": "...",
     "tools": [{"name": "gripper-A", "mass_kg": 2.0, "cog_mm": [40, -25, 70], "mass_std_kg": 0.002,
                "cog_std_mm": [0.5, 0.5, 0.6], "inertia_com_kgm2": [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] or null,
                "inertia_com_std_kgm2": [...] or null, "covariance_theta_si": [[4 numbers] × 4] or null,
                "number": 3, "run_dir": "...", "history_id": 12, "source": "identified",
                "time_utc": "...", "note": null}, ...]}

Version 2 adds ``covariance_theta_si`` (the library's schema version 2); version-1 documents (no
covariance) are still imported.

Import checks the whole document before it stores anything (a bad entry names its index and key);
imported entries are marked ``source: imported`` with the exporting robot and their original time in
``note``. An existing tool of the same name is kept unless ``replace`` is asked for.
"""

from __future__ import annotations

import json
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import Any

from payload_agent.errors import DataError
from payload_agent.tools.library import ToolEntry, check_entry, get, list_tools, store, utc_now

FORMAT = "payload-agent-tools/2"
READABLE = ("payload-agent-tools/1", FORMAT)


def export_document(db: Path, robot: str) -> dict[str, Any]:
    return {"format": FORMAT, "robot": robot, "exported_utc": utc_now(),
            "tools": [t.to_json() for t in list_tools(db, robot)]}


def _floats(v: Any, n: int, where: str) -> tuple[float, ...] | None:
    if v is None:
        return None
    if not isinstance(v, list) or len(v) != n or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                         for x in v):
        raise DataError(f"{where}: expected a list of {n} numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _matrix4(v: Any, where: str) -> tuple[tuple[float, ...], ...] | None:
    if v is None:
        return None
    if not isinstance(v, list) or len(v) != 4:
        raise DataError(f"{where}: expected 4 rows of 4 numbers (the covariance of [m, m·cx, m·cy, m·cz], SI), "
                        f"got {v!r}")
    return tuple(_floats(row, 4, f"{where}[{i}]") for i, row in enumerate(v))  # type: ignore[misc]


def parse_document(data: Any, source: str) -> tuple[str, list[ToolEntry]]:
    """(exporting robot, entries) of an export document; DataError naming the key that is wrong."""
    if not isinstance(data, dict):
        raise DataError(f"{source}: expected a JSON object with format, robot and tools")
    if data.get("format") not in READABLE:
        raise DataError(f"{source}: format: {data.get('format')!r}, expected one of {', '.join(READABLE)}")
    tools = data.get("tools")
    if not isinstance(tools, list):
        raise DataError(f"{source}: tools: expected a list")
    entries, seen = [], set()
    for i, t in enumerate(tools):
        where = f"{source}: tools[{i}]"
        if not isinstance(t, dict):
            raise DataError(f"{where}: expected an object")
        unknown = set(t) - set(ToolEntry.__dataclass_fields__) - {"cog_mm", "cog_std_mm"}
        if unknown:
            raise DataError(f"{where}: unknown keys {', '.join(sorted(unknown))}")
        for key in ("name", "mass_kg", "cog_mm"):
            if key not in t:
                raise DataError(f"{where}.{key}: missing")
        mass = t["mass_kg"]
        if not isinstance(mass, (int, float)) or isinstance(mass, bool):
            raise DataError(f"{where}.mass_kg: expected a number, got {mass!r}")
        std = t.get("mass_std_kg")
        if std is not None and (not isinstance(std, (int, float)) or isinstance(std, bool)):
            raise DataError(f"{where}.mass_std_kg: expected a number or null, got {std!r}")
        number = t.get("number")
        if number is not None and (not isinstance(number, int) or isinstance(number, bool)):
            raise DataError(f"{where}.number: expected an integer or null, got {number!r}")
        e = ToolEntry(name=str(t["name"]), mass_kg=float(mass), cog_mm=_floats(t["cog_mm"], 3, f"{where}.cog_mm"),
                      mass_std_kg=None if std is None else float(std),
                      cog_std_mm=_floats(t.get("cog_std_mm"), 3, f"{where}.cog_std_mm"),
                      inertia_com_kgm2=_floats(t.get("inertia_com_kgm2"), 6, f"{where}.inertia_com_kgm2"),
                      inertia_com_std_kgm2=_floats(t.get("inertia_com_std_kgm2"), 6, f"{where}.inertia_com_std_kgm2"),
                      number=number, run_dir=t.get("run_dir"), history_id=None, source="imported",
                      time_utc=str(t.get("time_utc") or ""), note=t.get("note"),
                      covariance_theta_si=_matrix4(t.get("covariance_theta_si"), f"{where}.covariance_theta_si"))
        check_entry(dc_replace(e, time_utc=e.time_utc or "x"), where)
        if e.name in seen:
            raise DataError(f"{where}.name: tool {e.name!r} appears twice")
        seen.add(e.name)
        entries.append(e)
    return str(data.get("robot", "?")), entries


def import_file(db: Path, robot: str, path: Path, replace: bool = False) -> tuple[list[ToolEntry], list[str]]:
    """Store every tool of an export file; returns (stored entries, names skipped because they exist)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: not a JSON tool library export ({exc})") from None
    origin, entries = parse_document(data, str(path))
    stored, skipped = [], []
    for e in entries:
        if get(db, robot, e.name) is not None and not replace:
            skipped.append(e.name)
            continue
        note = f"imported from robot {origin} ({path.name}), identified {e.time_utc or 'at an unknown time'}"
        stored.append(store(db, robot, dc_replace(e, time_utc=utc_now(), note=note), action="imported"))
    return stored, skipped
