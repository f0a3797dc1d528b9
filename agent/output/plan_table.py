"""The plan as a table with column headers (``plan``, and ``run`` before it asks to move)."""

from __future__ import annotations

import math
from typing import Any, Sequence

from payload_agent.motion.planner import Plan


def _move_name(kind: str, label: str) -> str:
    """The label without a repeated kind ("approach b-j2 start" in the approach row reads twice)."""
    return label[len(kind) + 1:] if label.startswith(kind + " ") else label


def format_plan(plan: Plan, durations: Sequence[float]) -> str:
    """One row per move: number, type, move, the six joint targets, speed and expected duration."""
    head = ["#", "type", "move", *[f"J{j} [deg]" for j in range(1, 7)], "speed [deg/s]", "time [s]"]
    rows = []
    for i, (m, d) in enumerate(zip(plan.moves, durations), 1):
        rows.append([str(i), m.kind, _move_name(m.kind, m.label), *[f"{math.degrees(v):.2f}" for v in m.target_rad],
                     f"{math.degrees(m.speed_rad_s):.2f}", "?" if not math.isfinite(d) else f"{d:.1f}"])
    widths = [max(len(r[c]) for r in [head, *rows]) for c in range(len(head))]
    left = {1, 2}

    def fmt(r: list[str]) -> str:
        return "  ".join(c.ljust(w) if k in left else c.rjust(w) for k, (c, w) in enumerate(zip(r, widths))).rstrip()

    known = [d for d in durations if math.isfinite(d)]
    total = sum(known)
    unknown = len(known) < len(durations)
    wrist = f", {len(plan.wrist_moves)} wrist moves for the inertia" if plan.wrist_moves else ""
    lines = [f"Plan: procedure {plan.procedure.name}, {len(plan.moves)} moves per run "
             f"({len(plan.sweeps)} recorded sweeps{wrist})", "  " + fmt(head), "  " + "  ".join("-" * w for w in widths)]
    lines += ["  " + fmt(r) for r in rows]
    lines.append(f"  robot time per run: {total:.1f} s" + (" plus the approach move (where the robot stands is "
                                                          "not known yet)" if unknown else ""))
    return "\n".join(lines)


def plan_json(plan: Plan, durations: Sequence[float]) -> dict[str, Any]:
    moves = []
    for i, (m, d) in enumerate(zip(plan.moves, durations), 1):
        moves.append({"index": i, **m.to_json(), "expected_s": round(d, 3) if math.isfinite(d) else None})
    known = [d for d in durations if math.isfinite(d)]
    return {"procedure": plan.procedure.name, "fingerprint": plan.fingerprint(), "moves": moves,
            "robot_time_s": round(sum(known), 3), "approach_known": len(known) == len(durations)}
