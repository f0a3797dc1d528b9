"""The robot's tool library: named tools, each with its identified payload, σ, source run and history.

Stored in ``<state>/<robot>/tools.sqlite`` (``tool_library_path``), next to the identification history
and with the same conventions (stdlib ``sqlite3``, WAL journal, ``PRAGMA user_version`` schema, a busy
timeout so a writer and readers can share the file; reading never creates it).

Two tables:

- ``tools``: the current entry of every named tool (one row per robot and name);
- ``tool_versions``: every value a tool ever had, and its removal, oldest first: the tool's history.
  A removed tool keeps its versions, so ``tools show`` can still say what it was.

Inertia: ``inertia_com_kgm2`` / ``inertia_com_std_kgm2``: the tensor about the centre of mass as
[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] and its standard uncertainties, kg·m², from the run's result when its
inertia identification gave one (None otherwise).

Covariance (schema version 2): ``covariance_theta_si``, the full 4×4 covariance of θ = [m, m·cx, m·cy, m·cz]
(kg, kg·m) exactly as the run's ``result.json`` carries it: mass and centre of mass are correlated,
and ``verify`` tests against this matrix rather than a diagonal built from the σ. A version-1 library
(σ only) is upgraded in place the first time this version opens it (``MIGRATIONS``); its entries keep
None there until re-identified.

A tool optionally has a ``number`` (1..65535, unique per robot): what a PLC or a tool changer
sends instead of the name (a register, an input pattern).
"""

from __future__ import annotations

import json
import math
import re
import sqlite3
from contextlib import closing
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from payload_agent.errors import DataError
from payload_agent.recording.sqlite_store import StoreSchema, open_for_write, read_rows

SCHEMA_VERSION = 2
LIBRARY_NAME = "tools.sqlite"
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9 ._+-]{0,63}$")
SOURCES = ("identified", "imported", "verified")

_FIELDS = ("mass_kg", "cog_x_mm", "cog_y_mm", "cog_z_mm", "mass_std_kg", "cog_std_x_mm", "cog_std_y_mm",
           "cog_std_z_mm", "inertia_com_kgm2", "inertia_com_std_kgm2", "number", "run_dir", "history_id",
           "source", "time_utc", "note", "covariance_theta_si")
_COLUMNS_SQL = """
    mass_kg REAL NOT NULL, cog_x_mm REAL NOT NULL, cog_y_mm REAL NOT NULL, cog_z_mm REAL NOT NULL,
    mass_std_kg REAL, cog_std_x_mm REAL, cog_std_y_mm REAL, cog_std_z_mm REAL,
    inertia_com_kgm2 TEXT,       -- JSON [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the CoM, kg·m²
    inertia_com_std_kgm2 TEXT,   -- JSON, their standard uncertainties
    number INTEGER,              -- what a PLC / tool changer sends for this tool, NULL if none
    run_dir TEXT, history_id INTEGER, source TEXT NOT NULL, time_utc TEXT NOT NULL, note TEXT,
    /* version 2: JSON, the 4×4 covariance of [m, m·cx, m·cy, m·cz], SI */ covariance_theta_si TEXT"""
_SCHEMA = (
    f"CREATE TABLE tools (robot TEXT NOT NULL, name TEXT NOT NULL, {_COLUMNS_SQL}, PRIMARY KEY (robot, name))",
    "CREATE UNIQUE INDEX tools_number ON tools (robot, number) WHERE number IS NOT NULL",
    f"CREATE TABLE tool_versions (id INTEGER PRIMARY KEY AUTOINCREMENT, robot TEXT NOT NULL, name TEXT NOT NULL, "
    f"action TEXT NOT NULL, {_COLUMNS_SQL})",
    "CREATE INDEX tool_versions_name ON tool_versions (robot, name, id)",
)
MIGRATIONS = {  # version k -> k + 1, applied in place (``sqlite_store``)
    1: ("ALTER TABLE tools ADD COLUMN covariance_theta_si TEXT",
        "ALTER TABLE tool_versions ADD COLUMN covariance_theta_si TEXT"),
}


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def tool_library_path(state_root: Path) -> Path:
    """The library of the robot whose state folder is ``state_root`` (``RobotState.root``)."""
    return Path(state_root) / LIBRARY_NAME


def check_name(name: str, where: str = "tool name") -> str:
    """A tool name: 1-64 characters, letters, digits, space and ``._+-``, starting with a letter or digit."""
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise DataError(f"{where}: {name!r} is not a usable tool name (1-64 characters: letters, digits, space, "
                        "'.', '_', '+', '-'; starting with a letter or digit)")
    return name


@dataclass(frozen=True)
class ToolEntry:
    """One tool's payload as the library holds it (masses kg, lengths mm, inertia kg·m² about the CoM)."""

    name: str
    mass_kg: float
    cog_mm: tuple[float, float, float]
    mass_std_kg: float | None = None
    cog_std_mm: tuple[float, float, float] | None = None
    inertia_com_kgm2: tuple[float, ...] | None = None  # [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the CoM
    inertia_com_std_kgm2: tuple[float, ...] | None = None  # their standard uncertainties
    number: int | None = None
    run_dir: str | None = None  # the run it was identified in
    history_id: int | None = None  # its row in history.sqlite
    source: str = "identified"  # identified | imported | verified
    time_utc: str = ""
    note: str | None = None
    covariance_theta_si: tuple[tuple[float, ...], ...] | None = None  # 4×4 of [m, m·cx, m·cy, m·cz], SI

    @property
    def cog_m(self) -> tuple[float, float, float]:
        return tuple(c / 1000.0 for c in self.cog_mm)  # type: ignore[return-value]

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "mass_kg": self.mass_kg, "cog_mm": list(self.cog_mm),
                "mass_std_kg": self.mass_std_kg, "cog_std_mm": None if self.cog_std_mm is None else list(self.cog_std_mm),
                "inertia_com_kgm2": None if self.inertia_com_kgm2 is None else list(self.inertia_com_kgm2),
                "inertia_com_std_kgm2": None if self.inertia_com_std_kgm2 is None else list(self.inertia_com_std_kgm2),
                "number": self.number, "run_dir": self.run_dir, "history_id": self.history_id,
                "source": self.source, "time_utc": self.time_utc, "note": self.note,
                "covariance_theta_si": None if self.covariance_theta_si is None
                else [list(row) for row in self.covariance_theta_si]}

    def inertia_tensor(self) -> np.ndarray | None:
        """The stored inertia about the CoM as the symmetric 3×3 tensor (flange axes), kg·m², or None."""
        if self.inertia_com_kgm2 is None:
            return None
        xx, yy, zz, xy, xz, yz = self.inertia_com_kgm2
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], float)

    def principal_inertia(self) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """(principal moments JX, JY, JZ kg·m², orientation A, B, C in degrees of their axes relative to the
        flange, intrinsic z-y'-x''): the OPC 40010 LoadType / KUKA form (``output.payload_forms``), or None."""
        tensor = self.inertia_tensor()
        if tensor is None:
            return None
        from payload_agent.output.payload_forms import payload_forms

        p = payload_forms(self.mass_kg, self.cog_m, tensor)["principal"]
        return tuple(p["j_kgm2"]), tuple(p["abc_deg"])

    def describe(self) -> str:
        m = f"{self.mass_kg:.4f} kg" + ("" if self.mass_std_kg is None else f" ± {1.96 * self.mass_std_kg:.4f}")
        c = "[" + ", ".join(f"{v:.1f}" for v in self.cog_mm) + "] mm"
        if self.cog_std_mm is not None:
            c += " ± [" + ", ".join(f"{1.96 * s:.1f}" for s in self.cog_std_mm) + "] (95 %)"
        num = "" if self.number is None else f" (number {self.number})"
        return f"{self.name}{num}: {m}, centre of mass {c}"


@dataclass(frozen=True)
class ToolVersion:
    """One stored value of a tool (or its removal), for ``tools show``."""

    id: int
    action: str  # stored | imported | removed
    entry: ToolEntry


# -- database ---------------------------------------------------------------------------------
STORE = StoreSchema("tool library", "tools", SCHEMA_VERSION, _SCHEMA, MIGRATIONS)


def _open_for_write(db: Path) -> sqlite3.Connection:
    return open_for_write(db, STORE)


def _read(db: Path, sql: str, args: tuple) -> list[sqlite3.Row]:
    return read_rows(db, STORE, sql, args)


def _row_values(e: ToolEntry) -> tuple:
    std = e.cog_std_mm if e.cog_std_mm is not None else (None, None, None)
    js = (lambda v: None if v is None else json.dumps([float(x) for x in v]))
    cov = None if e.covariance_theta_si is None else json.dumps([[float(x) for x in r] for r in e.covariance_theta_si])
    return (float(e.mass_kg), *(float(c) for c in e.cog_mm), e.mass_std_kg, *std, js(e.inertia_com_kgm2),
            js(e.inertia_com_std_kgm2), e.number, e.run_dir, e.history_id, e.source, e.time_utc or utc_now(), e.note,
            cov)


def _entry(r: sqlite3.Row) -> ToolEntry:
    std = (r["cog_std_x_mm"], r["cog_std_y_mm"], r["cog_std_z_mm"])
    tup = (lambda v: None if v is None else tuple(json.loads(v)))
    cov = r["covariance_theta_si"]
    return ToolEntry(r["name"], r["mass_kg"], (r["cog_x_mm"], r["cog_y_mm"], r["cog_z_mm"]), r["mass_std_kg"],
                     None if any(s is None for s in std) else std, tup(r["inertia_com_kgm2"]),
                     tup(r["inertia_com_std_kgm2"]), r["number"], r["run_dir"], r["history_id"], r["source"],
                     r["time_utc"], r["note"],
                     None if cov is None else tuple(tuple(float(x) for x in row) for row in json.loads(cov)))


def check_entry(e: ToolEntry, where: str = "tool") -> ToolEntry:
    """Refuse values no tool can have (a DataError naming the field)."""
    check_name(e.name, f"{where}.name")
    if not (math.isfinite(e.mass_kg) and e.mass_kg > 0):
        raise DataError(f"{where}.mass_kg: {e.mass_kg!r} is not a positive mass in kg")
    if len(e.cog_mm) != 3 or not all(math.isfinite(c) for c in e.cog_mm):
        raise DataError(f"{where}.cog_mm: expected three finite numbers [x, y, z] in mm, got {list(e.cog_mm)}")
    if e.mass_std_kg is not None and not (math.isfinite(e.mass_std_kg) and e.mass_std_kg >= 0):
        raise DataError(f"{where}.mass_std_kg: {e.mass_std_kg!r} is not a standard uncertainty (>= 0)")
    if e.cog_std_mm is not None and (len(e.cog_std_mm) != 3 or not all(math.isfinite(s) and s >= 0
                                                                       for s in e.cog_std_mm)):
        raise DataError(f"{where}.cog_std_mm: expected three standard uncertainties >= 0 in mm")
    for key in ("inertia_com_kgm2", "inertia_com_std_kgm2"):
        v = getattr(e, key)
        if v is not None and (len(v) != 6 or not all(math.isfinite(x) for x in v)):
            raise DataError(f"{where}.{key}: expected six numbers [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] in kg·m²")
    if e.covariance_theta_si is not None:
        check_covariance(e.covariance_theta_si, f"{where}.covariance_theta_si")
    if e.number is not None and not (isinstance(e.number, int) and 1 <= e.number <= 65535):
        raise DataError(f"{where}.number: {e.number!r} is not a tool number (an integer 1..65535)")
    if e.source not in SOURCES:
        raise DataError(f"{where}.source: {e.source!r} is not one of {', '.join(SOURCES)}")
    return e


def check_covariance(cov, where: str) -> None:
    """A covariance of θ: 4×4, finite, symmetric, positive semi-definite (a DataError naming ``where``)."""
    try:
        a = np.asarray(cov, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise DataError(f"{where}: expected a 4×4 matrix of finite numbers (the covariance of [m, m·cx, m·cy, m·cz], "
                        "SI)")
    scale = max(float(np.max(np.abs(a))), 1e-300)
    if np.max(np.abs(a - a.T)) > 1e-9 * scale:
        raise DataError(f"{where}: not symmetric")
    if float(np.min(np.linalg.eigvalsh(a))) < -1e-9 * scale:
        raise DataError(f"{where}: not positive semi-definite (a negative variance along some direction)")


def store(db: Path, robot: str, entry: ToolEntry, action: str = "stored") -> ToolEntry:
    """Insert or replace the tool's current entry and append it to its history; returns what was stored.

    A tool that had a number keeps it unless the new entry names one; a number another tool holds is refused.
    """
    entry = check_entry(replace(entry, time_utc=entry.time_utc or utc_now()))
    with closing(_open_for_write(db)) as conn:
        conn.execute("BEGIN IMMEDIATE")
        try:
            old = conn.execute("SELECT number FROM tools WHERE robot = ? AND name = ?", (robot, entry.name)).fetchone()
            if entry.number is None and old is not None and old["number"] is not None:
                entry = replace(entry, number=int(old["number"]))
            if entry.number is not None:
                other = conn.execute("SELECT name FROM tools WHERE robot = ? AND number = ? AND name != ?",
                                     (robot, entry.number, entry.name)).fetchone()
                if other is not None:
                    raise DataError(f"tool number {entry.number} already belongs to tool {other['name']!r} of "
                                    f"robot {robot}; remove or renumber that tool first")
            values = _row_values(entry)
            cols = ", ".join(_FIELDS)
            marks = ", ".join("?" for _ in _FIELDS)
            conn.execute(f"INSERT OR REPLACE INTO tools (robot, name, {cols}) VALUES (?, ?, {marks})",
                         (robot, entry.name, *values))
            conn.execute(f"INSERT INTO tool_versions (robot, name, action, {cols}) VALUES (?, ?, ?, {marks})",
                         (robot, entry.name, action, *values))
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
    return entry


def get(db: Path, robot: str, name: str) -> ToolEntry | None:
    rows = _read(db, "SELECT * FROM tools WHERE robot = ? AND name = ?", (robot, name))
    return _entry(rows[0]) if rows else None


def by_number(db: Path, robot: str, number: int) -> ToolEntry | None:
    rows = _read(db, "SELECT * FROM tools WHERE robot = ? AND number = ?", (robot, int(number)))
    return _entry(rows[0]) if rows else None


def require(db: Path, robot: str, name: str) -> ToolEntry:
    """The tool's entry, or a DataError listing the tools the library has."""
    entry = get(db, robot, name)
    if entry is None:
        known = [t.name for t in list_tools(db, robot)]
        raise DataError(f"no tool {name!r} in the tool library of robot {robot} ({db}); "
                        + (f"known: {', '.join(known)}" if known else "the library is empty: `payload-agent run "
                                                                         "--tool NAME` identifies and stores a tool"))
    return entry


def list_tools(db: Path, robot: str) -> list[ToolEntry]:
    return [_entry(r) for r in _read(db, "SELECT * FROM tools WHERE robot = ? ORDER BY name", (robot,))]


def versions(db: Path, robot: str, name: str) -> list[ToolVersion]:
    rows = _read(db, "SELECT * FROM tool_versions WHERE robot = ? AND name = ? ORDER BY id", (robot, name))
    return [ToolVersion(int(r["id"]), r["action"], _entry(r)) for r in rows]


def remove(db: Path, robot: str, name: str) -> ToolEntry:
    """Remove the tool's current entry (its history stays); DataError when there is none."""
    entry = require(db, robot, name)
    with closing(_open_for_write(db)) as conn:
        conn.execute("BEGIN IMMEDIATE")
        try:
            conn.execute("DELETE FROM tools WHERE robot = ? AND name = ?", (robot, name))
            cols = ", ".join(_FIELDS)
            conn.execute(f"INSERT INTO tool_versions (robot, name, action, {cols}) VALUES (?, ?, ?, "
                         f"{', '.join('?' for _ in _FIELDS)})", (robot, name, "removed", *_row_values(replace(entry, time_utc=utc_now()))))
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
    return entry


def store_result(db: Path, robot: str, name: str, result: dict[str, Any], history_id: int | None) -> ToolEntry:
    """Store an identification (a ``result.json`` dict whose quality passed) as the tool's current entry."""
    try:
        entry = ToolEntry(name=name, mass_kg=float(result["mass_kg"]),
                          cog_mm=tuple(float(c) for c in result["cog_mm"]),  # type: ignore[arg-type]
                          mass_std_kg=None if result.get("mass_std_kg") is None else float(result["mass_std_kg"]),
                          cog_std_mm=None if result.get("cog_std_mm") is None
                          else tuple(float(s) for s in result["cog_std_mm"]),  # type: ignore[arg-type]
                          inertia_com_kgm2=_opt6(result.get("inertia_com_kgm2")),
                          inertia_com_std_kgm2=_opt6(result.get("inertia_com_std_kgm2")),
                          run_dir=str(result.get("run_dir")), history_id=history_id, source="identified",
                          covariance_theta_si=_theta_cov(result.get("covariance_theta_si")))
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"the result cannot go into the tool library: {type(exc).__name__}: {exc}") from None
    return store(db, robot, entry)


def _theta_cov(v: Any) -> tuple[tuple[float, ...], ...] | None:
    """The [m, m·c] block of a result's ``covariance_theta_si`` (a fit with more parameters has more rows)."""
    if v is None:
        return None
    return tuple(tuple(float(x) for x in row[:4]) for row in v[:4])


def _opt6(v: Any) -> tuple[float, ...] | None:
    if v is None:
        return None
    flat = [float(x) for row in v for x in (row if isinstance(row, (list, tuple)) else [row])]
    if len(flat) == 9:  # a 3×3 tensor: its six independent entries
        flat = [flat[0], flat[4], flat[8], flat[1], flat[2], flat[5]]
    return tuple(flat)


def tool_name_arg(value: str) -> str:
    """argparse ``type`` for ``--tool``: refuses a name the library cannot hold before anything moves."""
    import argparse

    try:
        return check_name(value, "--tool")
    except DataError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
