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


def loop_sentence(loop: Any) -> str:
    """Whether the plan closes its loop (``SafetyGate.check_loop``'s verdict), as a sentence for ``plan``."""
    if loop.ok:
        return ("the plan closes its loop: a run may start where the last one ended (from the plan's end pose the "
                "safety gate passes the next run's approach)")
    return ("the plan does NOT close its loop: from where it ends the safety gate refuses the next run ("
            + "; ".join(loop.problems) + "), so a session recording the empty and the loaded run is refused before "
            "it moves, and each run needs the arm moved back within reach of the plan's start first")


def plan_json(plan: Plan, durations: Sequence[float]) -> dict[str, Any]:
    moves = []
    for i, (m, d) in enumerate(zip(plan.moves, durations), 1):
        moves.append({"index": i, **m.to_json(), "expected_s": round(d, 3) if math.isfinite(d) else None})
    known = [d for d in durations if math.isfinite(d)]
    return {"procedure": plan.procedure.name, "fingerprint": plan.fingerprint(), "moves": moves,
            "robot_time_s": round(sum(known), 3), "approach_known": len(known) == len(durations)}


def format_choice(choice: Any, mass_std_g: float, cog_std_mm: float, risk: float, limit: int = 12) -> str:
    """``plan --target-std``'s trade-off table (``evaluation.design.Choice``): the fastest usable candidates, and
    the chosen one always among its rows (marked), so the last line names a row the user can see. "robot s" is
    the whole run, the approach move included when it is known ("approach": that part, 0 when unknown). σ is what
    a typical run reports (the median), "P over" the chance that the run's σ exceeds the target (mass or centre of
    mass), which "meets" keeps at or below ``risk`` (``design.TARGET_RISK``)."""
    rows = [p for p in choice.table if p.usable][:limit]
    gap = choice.best is not None and choice.best not in rows
    if gap:
        rows.append(choice.best)
    lines = [f"target σ: mass {mass_std_g:g} g, centre of mass {cog_std_mm:g} mm (1σ); σ: a typical run's (median); "
             f"meets: the run's σ over the target in at most {100 * risk:g} % of runs (P over)",
             f"{'procedure':<56} {'robot s':>8} {'approach':>8} {'σ m g':>7} {'σ c mm':>7} {'P over':>6}  meets"]
    for p in rows:
        mark = ("yes" if p.meets(mass_std_g, cog_std_mm) else "") + ("  <- chosen" if p is choice.best else "")
        if gap and p is choice.best:
            lines.append("…  (faster rows that miss the target left out)")
        lines.append(f"{p.candidate.describe():<56} {p.robot_time_s:8.0f} {p.approach_s:8.0f} {p.mass_std_g:7.2f} "
                     f"{p.cog_std_mm:7.2f} {100 * p.p_over(mass_std_g, cog_std_mm):5.0f}%  {mark}".rstrip())
    lines.append("chosen: " + (f"{choice.best.candidate.describe()} ({choice.best.robot_time_s:.0f} s of robot time, "
                               f"{choice.best.approach_s:.0f} s of it the approach)" if choice.best
                               else "none meets the target; slower sweeps, a wider range or a calibration"))
    usable = [p for p in choice.table if p.usable]
    if choice.best is None and usable:  # how far the target is: the candidate nearest to it, and the least σ
        near = min(usable, key=lambda p: max(p.mass_std_g / mass_std_g, p.cog_std_mm / cog_std_mm))
        least_m = min(usable, key=lambda p: p.mass_std_g)
        lines.append(f"nearest: {near.candidate.describe()} ({near.robot_time_s:.0f} s): σ {near.mass_std_g:.2f} g, "
                     f"{near.cog_std_mm:.2f} mm; least mass σ of the {len(usable)} candidates {least_m.mass_std_g:.2f} g "
                     f"({least_m.candidate.describe()}, {least_m.robot_time_s:.0f} s)")
    return "\n".join(lines)
