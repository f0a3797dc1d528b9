"""The ``history`` command's terminal table: one row per identification, oldest first.

The run folder column shows the run's name, which ``solve`` and ``report`` accept in place of
its path (``payload_agent.recording.lookup``).
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Sequence

if TYPE_CHECKING:
    from payload_agent.recording.history import ChangeFlag, HistoryEntry


def format_history(history: Sequence[HistoryEntry], flags: Iterable[ChangeFlag] = (), *,
                   last: int | None = None) -> str:
    """A table, oldest first: one row per identification; ``!`` marks significant changes (explained below).

    ``last``: show only the most recent ``last`` rows (compute ``flags`` on the full history).
    """
    rows_src = sorted(history, key=lambda e: (e.time_utc, e.id if e.id is not None else 0))
    if last is not None:
        rows_src = rows_src[-last:] if last > 0 else []
    if not rows_src:
        return "No identifications in the history yet."
    by_id = {f.entry_id: f for f in flags}
    head = ["id", "time (UTC)", "tool", "solver", "mass [kg]", "cog x [mm]", "cog y [mm]", "cog z [mm]",
            "quality", "applied", "run folder", "change"]
    rows = []
    for e in rows_src:
        ci = e.cog_ci95_mm
        flag = by_id.get(e.id) if e.id is not None else None
        rows.append([
            str(e.id if e.id is not None else "-"), _short_time(e.time_utc), e.tool or "-", e.solver,
            _pm(e.mass_kg, e.mass_ci95_kg, 3),
            *[_pm(e.cog_mm[i], None if ci is None else ci[i], 1) for i in range(3)],
            {True: "ok", False: "FAILED", None: "-"}[e.quality_passed],
            "yes" if e.applied else "no", Path(e.run_dir).name if e.run_dir else "-",
            ("! " + ", ".join(flag.quantities)) if flag else "",
        ])
    widths = [max(len(r[c]) for r in [head, *rows]) for c in range(len(head))]
    right = {4, 5, 6, 7}
    fmt = lambda r: "  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths)))
    lines = [fmt(head).rstrip(), "  ".join("-" * w for w in widths)]
    lines += [fmt(r).rstrip() for r in rows]
    lines.append("(± = 95 % interval; ! = differs from the previous result for the same tool by more than the "
                 "combined 95 % interval)")
    shown = {e.id for e in rows_src}
    for f in flags:
        if f.entry_id in shown:
            lines.append("  " + f.describe())
    return "\n".join(lines)


def _short_time(iso: str) -> str:
    try:
        t = datetime.fromisoformat(iso).astimezone(timezone.utc)
    except ValueError:
        return iso
    return t.strftime("%Y-%m-%d %H:%M")


def _pm(value: float, half: float | None, digits: int) -> str:
    if half is None or not math.isfinite(half):
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ± {half:.{digits}f}"
