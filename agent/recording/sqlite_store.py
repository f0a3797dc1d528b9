"""The robot state folder's SQLite files (the history, the tool library): opened one way.

Each file carries its schema version in ``PRAGMA user_version``. A new file gets its schema in
one ``BEGIN IMMEDIATE`` transaction, so two first writers (a `watch` run and a manual `run`)
cannot both create it; a file written by a newer payload-agent, or a table of the right name
without a version, is refused with what to do rather than read wrongly. A file of an older
version is upgraded in place, in one ``BEGIN IMMEDIATE`` transaction, by the schema's migrations
(statements from version k to k + 1, applied in order), the first time it is opened, for reading
too: a crash mid-way leaves the old version intact. Writers use WAL so readers are never blocked;
connections are in autocommit mode (transactions are explicit).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

from payload_agent.errors import DataError

BUSY_TIMEOUT_S = 10.0  # another process writing the same file: wait this long before giving up


@dataclass(frozen=True)
class StoreSchema:
    what: str  # how the file is named to the user, e.g. "history database"
    table: str  # the main table: its presence without a version means a foreign file
    version: int
    statements: Sequence[str]  # CREATE TABLE / INDEX statements of this version
    migrations: Mapping[int, Sequence[str]] = field(default_factory=dict)  # k: statements from version k to k + 1


def connect(db: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(str(db), timeout=BUSY_TIMEOUT_S, isolation_level=None)
    conn.row_factory = sqlite3.Row
    return conn


def _ensure_schema(conn: sqlite3.Connection, db: Path, schema: StoreSchema) -> None:
    version = conn.execute("PRAGMA user_version").fetchone()[0]
    if version == schema.version:
        return
    if version > schema.version:
        raise DataError(f"{db}: {schema.what} schema version {version} was written by a newer payload-agent "
                        f"(this one reads version {schema.version}); upgrade payload-agent")
    missing = [k for k in range(max(version, 1), schema.version) if k not in schema.migrations]
    if version > 0 and missing:
        raise DataError(f"{db}: {schema.what} schema version {version} cannot be upgraded to {schema.version} by "
                        f"this payload-agent (no migration from version {missing[0]})")
    conn.execute("BEGIN IMMEDIATE")
    try:
        version = conn.execute("PRAGMA user_version").fetchone()[0]  # another process may have done it meanwhile
        if version == 0:
            if conn.execute("SELECT name FROM sqlite_master WHERE name = ?", (schema.table,)).fetchone():
                raise DataError(f"{db}: has a {schema.table} table but no schema version; not a payload-agent "
                                f"{schema.what} (move it away)")
            for stmt in schema.statements:
                conn.execute(stmt)
        else:
            for k in range(version, schema.version):
                for stmt in schema.migrations[k]:
                    conn.execute(stmt)
        conn.execute(f"PRAGMA user_version = {int(schema.version)}")
        conn.execute("COMMIT")
    except BaseException:
        conn.execute("ROLLBACK")
        raise


def open_for_write(db: Path, schema: StoreSchema) -> sqlite3.Connection:
    """A connection that may write: the file and its schema are created when missing."""
    db = Path(db)
    db.parent.mkdir(parents=True, exist_ok=True)
    conn = connect(db)
    try:
        conn.execute("PRAGMA journal_mode = WAL")
        _ensure_schema(conn, db, schema)
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise DataError(f"{db}: not a usable {schema.what} ({exc})") from None
    except BaseException:
        conn.close()
        raise
    return conn


def read_rows(db: Path, schema: StoreSchema, sql: str, args: Sequence = ()) -> list[sqlite3.Row]:
    """The rows of a query; none when the file or its schema does not exist yet (nothing stored)."""
    from contextlib import closing

    db = Path(db)
    if not db.exists():
        return []
    try:
        with closing(connect(db)) as conn:
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            if version == 0:
                return []
            if version > schema.version:
                raise DataError(f"{db}: {schema.what} schema version {version} was written by a newer "
                                f"payload-agent (this one reads version {schema.version}); upgrade payload-agent")
        if version < schema.version:  # an older file: upgraded in place first (see the module docstring)
            open_for_write(db, schema).close()
        with closing(connect(db)) as conn:
            return conn.execute(sql, tuple(args)).fetchall()
    except sqlite3.DatabaseError as exc:
        raise DataError(f"{db}: not a usable {schema.what} ({exc})") from None
