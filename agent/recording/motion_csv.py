"""Recordings of motion the agent did not make: RTDE CSV files and other tables of joint data.

Two layouts are read:

- **With a header** (what ur-rtde's ``RTDEReceiveInterface.startFileRecording`` writes, comma
  separated, and UR's RTDE client example ``record.py``, space separated): one column per
  value, named by the RTDE output and its index, ``timestamp``, ``actual_q_0`` … ``actual_q_5``,
  ``actual_current_0`` …, ``target_current_0`` …, ``target_moment_0`` ….
- **Without a header**, described by a column map: the columns' names in file order, where
  ``name[6]`` stands for six columns ``name_0`` … ``name_5`` and ``-`` for a column to ignore,
  e.g. ``timestamp,actual_q[6],actual_qd[6],actual_current[6],target_current[6],target_moment[6]``.

Needed: ``timestamp`` [s], ``actual_q`` [rad] and an effort, ``actual_current`` [A] (or
``actual_joint_torque`` / ``effort`` in N·m for controllers that give torque). ``target_current``
and ``target_moment`` are kept when present: they let the agent derive the drives' own
current-to-torque constants (``evaluation.torque_constants``).

Real logs start with rubbish now and then (short rows, a value in the millions while the
recorder attaches): such rows are dropped, counted and described, never guessed at. A row that
is bad in the middle of the recording is an error naming the file and line: the data there is
not what the file says it is.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from payload_agent.errors import DataError

N_JOINTS = 6
TIME = "timestamp"
ANGLES = "actual_q"
CURRENT = "actual_current"
TORQUE_NAMES = ("actual_joint_torque", "effort")  # controllers that stream N·m (not RTDE: a column map names it)
TARGET_CURRENT = "target_current"
TARGET_MOMENT = "target_moment"
VELOCITY = "actual_qd"
VECTORS = (ANGLES, VELOCITY, CURRENT, TARGET_CURRENT, TARGET_MOMENT) + TORQUE_NAMES
# Rows at the start of a log may be rubbish; a value beyond these is not a reading (rad, A, N·m)
PLAUSIBLE = {ANGLES: 4 * math.pi, VELOCITY: 10.0, CURRENT: 100.0, TARGET_CURRENT: 100.0, TARGET_MOMENT: 2000.0,
             "actual_joint_torque": 2000.0, "effort": 2000.0}
MAX_LEADING_RUBBISH = 50  # more bad rows than this at the start: the map is wrong, not the recorder


@dataclass(frozen=True)
class MotionRecording:
    """One recording of joint motion, SI units, rows in time order."""

    source: str
    t: np.ndarray  # (n,) s, the controller's clock
    q: np.ndarray  # (n, 6) rad
    current_a: np.ndarray | None  # (n, 6) A, actual motor current
    torque_nm: np.ndarray | None  # (n, 6) N·m, where the controller streams torque instead of current
    target_current_a: np.ndarray | None = None
    target_moment_nm: np.ndarray | None = None
    qd: np.ndarray | None = None  # (n, 6) rad/s, the controller's joint speed where recorded
    dropped: tuple[str, ...] = field(default_factory=tuple)  # what was left out and why (one line each)

    @property
    def rows(self) -> int:
        return len(self.t)

    @property
    def period_s(self) -> float:
        return float(np.median(np.diff(self.t)))

    @property
    def effort_unit(self) -> str:
        return "A" if self.current_a is not None else "Nm"

    @property
    def effort(self) -> np.ndarray:
        return self.current_a if self.current_a is not None else self.torque_nm


def parse_column_map(text: str) -> list[str]:
    """``timestamp,actual_q[6],-,...`` → one name per file column (``-`` ignored); raises on a bad entry."""
    names: list[str] = []
    for raw in text.split(","):
        item = raw.strip()
        m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?|-", item)
        if not m:
            raise DataError(f"column map: {item!r} is not a column name, name[count] or '-' "
                            f"(e.g. timestamp,actual_q[6],actual_current[6])")
        if item == "-":
            names.append("-")
        elif m.group(2) is not None:
            names += [f"{m.group(1)}_{k}" for k in range(int(m.group(2)))]
        else:
            names.append(item)
    return names


def _split(line: str) -> list[str]:
    return [p for p in re.split(r"[,\s;]+", line.strip()) if p]


def _is_header(fields: list[str]) -> bool:
    try:
        [float(f) for f in fields]
    except ValueError:
        return True
    return False


def _vector(columns: dict[str, int], name: str, where: str, required: bool) -> list[int] | None:
    idx = [columns.get(f"{name}_{k}") for k in range(N_JOINTS)]
    if all(i is None for i in idx):
        if required:
            raise DataError(f"{where}: no {name}_0 … {name}_5 columns (have: {', '.join(list(columns)[:12])}…)")
        return None
    missing = [f"{name}_{k}" for k, i in enumerate(idx) if i is None]
    if missing:
        raise DataError(f"{where}: {', '.join(missing)} missing (the other {name} columns are there)")
    return idx  # type: ignore[return-value]


def read_motion_csv(path: str | Path, column_map: str | None = None) -> MotionRecording:
    """Read one recording; ``column_map`` for a file without a header (refused for one with a header)."""
    path = Path(path)
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise DataError(f"cannot read the recording {path}: {exc.strerror or exc}") from None
    first = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")), None)
    if first is None:
        raise DataError(f"{path}: the file is empty")
    head = _split(lines[first].lstrip("#"))
    if _is_header(head):
        if column_map:
            raise DataError(f"{path}: the file has a header line ({', '.join(head[:4])}, …); leave the column map "
                            "out, the header names the columns")
        names, body = head, first + 1
    elif column_map:
        names, body = parse_column_map(column_map), first
    else:
        raise DataError(f"{path}: no header line and no column map: say what the columns are, e.g. --columns "
                        "'timestamp,actual_q[6],actual_qd[6],actual_current[6],target_current[6],target_moment[6]'")
    columns = {n: i for i, n in enumerate(names) if n != "-"}
    where = str(path)
    if TIME not in columns:
        raise DataError(f"{where}: no {TIME} column (the controller's time in s)")
    picks = {name: _vector(columns, name, where, required=name == ANGLES) for name in VECTORS}
    effort_name = next((n for n in (CURRENT,) + TORQUE_NAMES if picks[n] is not None), None)
    if effort_name is None:
        raise DataError(f"{where}: no effort columns: {CURRENT}_0 … (A) or {TORQUE_NAMES[0]}_0 … (N·m)")
    wanted = {n: ix for n, ix in picks.items() if ix is not None}
    rows, dropped, leading = [], [], True
    for lineno in range(body, len(lines)):
        text = lines[lineno]
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        fields = _split(text)
        problem = None
        if len(fields) != len(names):
            problem = f"{len(fields)} values where the columns need {len(names)}"
        else:
            try:
                values = [float(f) for f in fields]
            except ValueError:
                problem = "a value that is not a number"
            else:
                for n, ix in wanted.items():
                    bad = [k for k, i in enumerate(ix) if not abs(values[i]) <= PLAUSIBLE[n]]
                    if bad:
                        problem = f"{n}_{bad[0]} = {values[ix[bad[0]]]:g} is not a reading"
                        break
                if problem is None and not math.isfinite(values[columns[TIME]]):
                    problem = f"{TIME} is not a number"
        if problem is None:
            leading = False
            rows.append(values)
            continue
        if not leading:
            raise DataError(f"{where}, line {lineno + 1}: {problem}; the recording is damaged there "
                            "(only rows before the first good one are dropped)")
        dropped.append(f"line {lineno + 1}: {problem}")
        if len(dropped) > MAX_LEADING_RUBBISH:
            raise DataError(f"{where}: the first {len(dropped)} rows are not readings ({dropped[0]}): "
                            "check the column map against the file")
    if len(rows) < 10:
        raise DataError(f"{where}: only {len(rows)} readable rows")
    data = np.asarray(rows, float)
    t = data[:, columns[TIME]]
    keep = np.concatenate([[True], np.diff(t) > 0])
    if not keep.all():  # a repeated or earlier timestamp: the recorder wrote the same package twice
        dropped.append(f"{int((~keep).sum())} rows whose {TIME} did not advance")
        data, t = data[keep], t[keep]
    if not np.all(np.diff(t) > 0):
        raise DataError(f"{where}: {TIME} goes backwards; the rows are not in time order")

    def take(name: str) -> np.ndarray | None:
        ix = wanted.get(name)
        return None if ix is None else data[:, ix]

    return MotionRecording(where, t, take(ANGLES), take(CURRENT),
                           take(effort_name) if effort_name != CURRENT else None,
                           take(TARGET_CURRENT), take(TARGET_MOMENT), take(VELOCITY), tuple(dropped))
