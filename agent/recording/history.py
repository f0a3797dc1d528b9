"""Per-robot history of identifications: one SQLite row per result, applied or not.

The database lives at ``RobotState.for_config(config).history_db``
(``<storage.state_dir>/<robot>/history.sqlite``). It answers the operator's questions
"what did this tool weigh last time?", "was it written to the controller?" and "did the
tool change?" without opening run folders.

Storage
    stdlib ``sqlite3``; the schema version is ``PRAGMA user_version`` (``SCHEMA_VERSION``),
    the table is created on first ``record``. WAL journal plus a busy timeout, so one
    writer (a run, `watch`) and any number of readers (`history`, `report`) can use the
    file at the same time. Reading never creates the file.

Comparison rule (``compare_to_previous``)
    A result is compared with the most recent *earlier* result for the same tool label on
    the same robot. Results without a label (``tool=None``) form their own series and are
    compared with the previous unlabeled result: an unlabeled run says nothing about which
    tool was mounted, so comparing it with a labeled one would flag every tool change.
    A quantity is flagged when it moved by more than its combined 95 % uncertainty,
    |Δ| > 1.96·sqrt(σ₁² + σ₂²), for the mass and for each centre-of-mass axis. Results
    without a standard uncertainty (the three-step solver reports none) are not compared:
    no honest threshold exists for them. Quality-failed results take part like any other;
    the table shows their failed quality next to them.
"""

from __future__ import annotations

import json
import math
import sqlite3
from contextlib import closing
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

from payload_agent.version import __version__
from payload_agent.types import PayloadSetting
from payload_agent.errors import DataError
from payload_agent.recording.sqlite_store import StoreSchema, open_for_write, read_rows

SCHEMA_VERSION = 1
Z95 = 1.96

_COLUMNS = (
    "time_utc", "robot", "run_dir", "tool", "solver", "mass_kg", "cog_x_mm", "cog_y_mm", "cog_z_mm",
    "mass_std_kg", "cog_std_x_mm", "cog_std_y_mm", "cog_std_z_mm", "quality_passed", "quality_reasons",
    "applied", "applied_utc", "applied_mass_kg", "applied_cog_mm", "applied_tool_num", "baseline_run_dir",
    "baseline_fingerprint", "gains_note", "software_version", "config_fingerprint",
)

_SCHEMA_V1 = (
"""CREATE TABLE identifications (
    id                   INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc             TEXT    NOT NULL,  -- ISO 8601, UTC, when the result was recorded
    robot                TEXT    NOT NULL,
    run_dir              TEXT    NOT NULL,
    tool                 TEXT,              -- operator's label (--tool), NULL when none was given
    solver               TEXT    NOT NULL,
    mass_kg              REAL    NOT NULL,
    cog_x_mm             REAL    NOT NULL,
    cog_y_mm             REAL    NOT NULL,
    cog_z_mm             REAL    NOT NULL,
    mass_std_kg          REAL,              -- standard uncertainty (95 % half-width = 1.96 x this)
    cog_std_x_mm         REAL,
    cog_std_y_mm         REAL,
    cog_std_z_mm         REAL,
    quality_passed       INTEGER,           -- 1/0, NULL when no quality checks were recorded
    quality_reasons      TEXT    NOT NULL DEFAULT '[]',  -- JSON list of sentences
    applied              INTEGER NOT NULL DEFAULT 0,
    applied_utc          TEXT,
    applied_mass_kg      REAL,              -- what the controller reported back after the write
    applied_cog_mm       TEXT,              -- JSON [x, y, z]
    applied_tool_num     INTEGER,
    baseline_run_dir     TEXT,              -- run folder whose empty phase was subtracted
    baseline_fingerprint TEXT,
    gains_note           TEXT,
    software_version     TEXT    NOT NULL,
    config_fingerprint   TEXT
)""",
"CREATE INDEX identifications_tool_time ON identifications (robot, tool, time_utc)",
)  # statements, run one by one inside one transaction
STORE = StoreSchema("history database", "identifications", SCHEMA_VERSION, _SCHEMA_V1)


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


@dataclass
class HistoryEntry:
    """One identification as stored in the history (lengths in mm, masses in kg)."""

    robot: str
    run_dir: str
    solver: str
    mass_kg: float
    cog_mm: tuple[float, float, float]
    mass_std_kg: float | None = None
    cog_std_mm: tuple[float, float, float] | None = None
    quality_passed: bool | None = None
    quality_reasons: list[str] = field(default_factory=list)
    tool: str | None = None
    time_utc: str = field(default_factory=utc_now)
    applied: bool = False
    applied_utc: str | None = None
    applied_mass_kg: float | None = None
    applied_cog_mm: tuple[float, float, float] | None = None
    applied_tool_num: int | None = None
    baseline_run_dir: str | None = None
    baseline_fingerprint: str | None = None
    gains_note: str | None = None
    software_version: str = __version__
    config_fingerprint: str | None = None
    id: int | None = None  # set by record() / entries()

    @property
    def mass_ci95_kg(self) -> float | None:
        return None if self.mass_std_kg is None else Z95 * self.mass_std_kg

    @property
    def cog_ci95_mm(self) -> tuple[float, float, float] | None:
        return None if self.cog_std_mm is None else tuple(Z95 * s for s in self.cog_std_mm)

    @classmethod
    def from_result_json(cls, result: Mapping[str, Any], *, tool: str | None = None,
                         baseline_run_dir: str | None = None, baseline_fingerprint: str | None = None,
                         gains_note: str | None = None, config_fingerprint: str | None = None,
                         software_version: str = __version__, time_utc: str | None = None) -> "HistoryEntry":
        """Build an entry from a result.json dict (``RunResult.to_json()`` or the file's contents)."""
        try:
            cog = tuple(float(v) for v in result["cog_mm"])
            if len(cog) != 3:
                raise ValueError("cog_mm must have 3 values")
            entry = cls(robot=str(result["robot"]), run_dir=str(result["run_dir"]), solver=str(result["solver"]),
                         mass_kg=float(result["mass_kg"]), cog_mm=cog)  # type: ignore[arg-type]
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"the result cannot go into the history: {type(exc).__name__}: {exc} "
                            "(expected robot, run_dir, solver, mass_kg and cog_mm [x, y, z])") from None
        if result.get("mass_std_kg") is not None:
            entry.mass_std_kg = float(result["mass_std_kg"])
        if result.get("cog_std_mm") is not None:
            entry.cog_std_mm = tuple(float(v) for v in result["cog_std_mm"])  # type: ignore[assignment]
        quality = result.get("quality") or {}
        if quality:
            entry.quality_passed = bool(quality.get("passed"))
            entry.quality_reasons = [str(r) for r in quality.get("reasons", [])]
        entry.tool = tool
        entry.baseline_run_dir = baseline_run_dir
        entry.baseline_fingerprint = baseline_fingerprint
        entry.gains_note = gains_note
        entry.config_fingerprint = config_fingerprint
        entry.software_version = software_version
        if time_utc is not None:
            entry.time_utc = time_utc
        return entry


@dataclass(frozen=True)
class ChangeFlag:
    """A result that differs from the previous result for the same tool by more than its uncertainty."""

    entry_id: int
    previous_id: int
    tool: str | None
    quantities: tuple[str, ...]  # "mass", "cog x", "cog y", "cog z": what moved significantly
    mass_delta_kg: float
    mass_limit_kg: float  # 1.96·sqrt(σ₁² + σ₂²)
    cog_delta_mm: tuple[float, float, float]
    cog_limit_mm: tuple[float, float, float]

    def describe(self) -> str:
        parts = []
        for q in self.quantities:
            if q == "mass":
                parts.append(f"mass {self.mass_delta_kg:+.4f} kg (limit ±{self.mass_limit_kg:.4f})")
            else:
                i = "xyz".index(q[-1])
                parts.append(f"{q} {self.cog_delta_mm[i]:+.1f} mm (limit ±{self.cog_limit_mm[i]:.1f})")
        label = "unlabeled tool" if self.tool is None else f"tool {self.tool!r}"
        return f"#{self.entry_id} differs from #{self.previous_id} ({label}): " + ", ".join(parts)


# -- database ---------------------------------------------------------------------------------
def _open_for_write(db_path: Path) -> sqlite3.Connection:
    return open_for_write(db_path, STORE)


def record(db_path: Path, entry: HistoryEntry) -> int:
    """Append one identification; returns its id (also set on ``entry.id``). Creates the database."""
    values = _to_row(entry)
    with closing(_open_for_write(db_path)) as conn:
        cur = conn.execute(f"INSERT INTO identifications ({', '.join(_COLUMNS)}) "
                           f"VALUES ({', '.join('?' for _ in _COLUMNS)})", values)
        entry.id = int(cur.lastrowid)
    return entry.id


def mark_applied(db_path: Path, entry_id: int, readback: PayloadSetting, *, time_utc: str | None = None) -> None:
    """Record that entry ``entry_id`` was written to the controller, with what the controller read back."""
    cog_mm = [1000.0 * float(v) for v in readback.cog_m]
    with closing(_open_for_write(db_path)) as conn:
        cur = conn.execute(
            "UPDATE identifications SET applied = 1, applied_utc = ?, applied_mass_kg = ?, applied_cog_mm = ?, "
            "applied_tool_num = ? WHERE id = ?",
            (time_utc or utc_now(), float(readback.mass_kg), json.dumps(cog_mm), readback.tool_num, int(entry_id)))
        if cur.rowcount != 1:
            raise DataError(f"{db_path}: no history entry #{entry_id} to mark as applied")


def entries(db_path: Path, tool: str | None = None, limit: int | None = None, *,
            robot: str | None = None) -> list[HistoryEntry]:
    """Stored identifications, oldest first.

    ``tool``: only that label (None = every entry, labeled or not). ``limit``: only the most
    recent ``limit`` entries. ``robot``: only that robot (one database normally holds one).
    A missing database is an empty history (nothing is created).
    """
    db_path = Path(db_path)
    if not db_path.exists():
        return []
    where, args = [], []
    if tool is not None:
        where.append("tool = ?")
        args.append(tool)
    if robot is not None:
        where.append("robot = ?")
        args.append(robot)
    sql = "SELECT * FROM identifications" + (" WHERE " + " AND ".join(where) if where else "")
    sql += " ORDER BY time_utc DESC, id DESC"
    if limit is not None:
        sql += " LIMIT ?"
        args.append(int(limit))
    rows = read_rows(db_path, STORE, sql, args)
    return [_from_row(r) for r in reversed(rows)]


def _to_row(e: HistoryEntry) -> tuple:
    std = e.cog_std_mm if e.cog_std_mm is not None else (None, None, None)
    return (e.time_utc, e.robot, e.run_dir, e.tool, e.solver, float(e.mass_kg), *map(float, e.cog_mm),
            e.mass_std_kg, *std, None if e.quality_passed is None else int(bool(e.quality_passed)),
            json.dumps(list(e.quality_reasons)), int(bool(e.applied)), e.applied_utc, e.applied_mass_kg,
            None if e.applied_cog_mm is None else json.dumps(list(e.applied_cog_mm)), e.applied_tool_num,
            e.baseline_run_dir, e.baseline_fingerprint, e.gains_note, e.software_version, e.config_fingerprint)


def _from_row(r: sqlite3.Row) -> HistoryEntry:
    std = (r["cog_std_x_mm"], r["cog_std_y_mm"], r["cog_std_z_mm"])
    return HistoryEntry(
        id=int(r["id"]), time_utc=r["time_utc"], robot=r["robot"], run_dir=r["run_dir"], tool=r["tool"],
        solver=r["solver"], mass_kg=r["mass_kg"], cog_mm=(r["cog_x_mm"], r["cog_y_mm"], r["cog_z_mm"]),
        mass_std_kg=r["mass_std_kg"], cog_std_mm=None if any(s is None for s in std) else std,
        quality_passed=None if r["quality_passed"] is None else bool(r["quality_passed"]),
        quality_reasons=json.loads(r["quality_reasons"] or "[]"), applied=bool(r["applied"]),
        applied_utc=r["applied_utc"], applied_mass_kg=r["applied_mass_kg"],
        applied_cog_mm=None if r["applied_cog_mm"] is None else tuple(json.loads(r["applied_cog_mm"])),
        applied_tool_num=r["applied_tool_num"], baseline_run_dir=r["baseline_run_dir"],
        baseline_fingerprint=r["baseline_fingerprint"], gains_note=r["gains_note"],
        software_version=r["software_version"], config_fingerprint=r["config_fingerprint"])


# -- comparison -------------------------------------------------------------------------------
def compare_pair(previous: HistoryEntry, current: HistoryEntry) -> ChangeFlag | None:
    """The flag for ``current`` against ``previous``, or None if nothing moved beyond its uncertainty
    (or if either lacks an uncertainty, so no threshold can be set)."""
    if previous.mass_std_kg is None or current.mass_std_kg is None:
        return None
    dm = current.mass_kg - previous.mass_kg
    lim_m = Z95 * math.hypot(previous.mass_std_kg, current.mass_std_kg)
    quantities = ["mass"] if abs(dm) > lim_m else []
    dc = tuple(c - p for c, p in zip(current.cog_mm, previous.cog_mm))
    if previous.cog_std_mm is not None and current.cog_std_mm is not None:
        lim_c = tuple(Z95 * math.hypot(a, b) for a, b in zip(previous.cog_std_mm, current.cog_std_mm))
        quantities += [f"cog {ax}" for ax, d, lim in zip("xyz", dc, lim_c) if abs(d) > lim]
    else:
        lim_c = (math.nan, math.nan, math.nan)
    if not quantities:
        return None
    return ChangeFlag(int(current.id if current.id is not None else -1),
                      int(previous.id if previous.id is not None else -1), current.tool, tuple(quantities),
                      dm, lim_m, dc, lim_c)  # type: ignore[arg-type]


def compare_to_previous(history: Sequence[HistoryEntry]) -> list[ChangeFlag]:
    """Flags for every entry that differs significantly from the previous one of the same tool series.

    Series: same robot and same tool label (None is its own series). Order: by time, then id.
    Pass the whole history (not a ``limit``-ed tail) so the first shown entry has its predecessor.
    """
    ordered = sorted(history, key=lambda e: (e.time_utc, e.id if e.id is not None else 0))
    last: dict[tuple[str, str | None], HistoryEntry] = {}
    flags = []
    for e in ordered:
        key = (e.robot, e.tool)
        prev = last.get(key)
        if prev is not None:
            flag = compare_pair(prev, e)
            if flag is not None:
                flags.append(flag)
        last[key] = e
    return flags


def flag_for(db_path: Path, entry_id: int) -> ChangeFlag | None:
    """The change flag of one stored entry (e.g. the one just recorded), or None."""
    for f in compare_to_previous(entries(db_path)):
        if f.entry_id == entry_id:
            return f
    return None


def entry_json(e: HistoryEntry) -> dict[str, Any]:
    """One entry for ``history --json``: every stored field plus the 95 % half-widths."""
    from dataclasses import asdict

    d = asdict(e)
    d["mass_ci95_kg"] = e.mass_ci95_kg
    d["cog_ci95_mm"] = None if e.cog_ci95_mm is None else list(e.cog_ci95_mm)
    return d
