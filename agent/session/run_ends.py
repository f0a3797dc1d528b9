"""Where a session's runs start and end, beyond the plan's own moves: the first run from our own resting pose at
travel speed, the last one back to where the session started (a tool change), or parked at the plan's first pose
(`calibrate --park`). Each is a change of the selected runs' plans before anything moves, so the safety gate checks
it with the rest of them (``runner._show_and_confirm``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.motion.planner import Move, Plan, from_resting_pose, parked
from payload_agent.session.modes import Selection


def returning(config: Config, chosen: Selection, start_q) -> Selection:
    """``chosen`` whose last phase ends with a travel move back to ``start_q``, where the arm stood before the
    session's first move (``RunOptions.return_to_start``); the gate checks it with the rest of that phase."""
    phase, mounted, last = chosen.todo[-1]
    travel = config.robot.max_joint_speed_rad_s * config.procedure.travel_speed_percent / 100.0
    accel = next((m.accel_rad_s2 for m in reversed(last.moves) if m.kind == "travel"), last.moves[-1].accel_rad_s2)
    back = Move("return to where the session started", "travel", tuple(float(v) for v in start_q), travel, accel)
    return replace(chosen, todo=[*chosen.todo[:-1], (phase, mounted, Plan(last.procedure, (*last.moves, back)))])


def parking(config: Config, chosen: Selection, out) -> Selection:
    """``chosen`` whose last run ends at the plan's first pose (``RunOptions.park``, ``motion.planner.parked``), and
    the session says where that move goes (with two runs the table shows the first run's moves only)."""
    phase, mounted, last = chosen.todo[-1]
    ending = parked(config, last)
    if ending is not last:
        q = ", ".join(f"{np.degrees(v):.1f}" for v in ending.moves[-1].target_rad)
        out(f"The {'loaded' if mounted else 'empty-flange'} run ends with a park move back to the plan's first pose "
            f"[{q}] deg at travel speed (--park): the arm waits there for the tool change, and a run of this plan "
            "then starts there with no approach")
    return replace(chosen, todo=[*chosen.todo[:-1], (phase, mounted, ending)])


def from_rest(config: Config, chosen: Selection) -> Selection:
    """``chosen`` whose first run leaves our own resting pose at travel speed (``motion.planner.from_resting_pose``);
    a later run of the session still approaches its start slowly."""
    phase, mounted, first = chosen.todo[0]
    return replace(chosen, todo=[(phase, mounted, from_resting_pose(config, first)), *chosen.todo[1:]])
