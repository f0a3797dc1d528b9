"""A simulated robot that starts where its plan's first move goes.

The shipped sim-*.yaml start their arm far from the plan (as a real arm stands wherever the last program left
it), so a fresh session's first move is the slow approach: at 5 % of the EC66's 144°/s, 12-25 s of simulated
travel, 6-12 s of wall time at the fault matrix's time scale 2. Runs whose subject is not the approach (the
fault matrix's cells, most of the test suite's sessions) start at the approach's target instead; the approach
move itself is still planned, safety-checked and sent (it has nothing to travel).
"""

from __future__ import annotations

import copy
import math
from typing import Any

from payload_agent.configuration.config import parse_config
from payload_agent.motion.planner import make_plan


def start_at_first_move(data: dict[str, Any], base_dir=None) -> dict[str, Any]:
    """A copy of a simulated robot's YAML dict with ``simulation.start_deg`` at the target of the plan's first
    move (the approach). ``base_dir``: where relative paths in the YAML are read from, as for parse_config."""
    target = make_plan(parse_config(data, source="start_at_first_move", base_dir=base_dir)).moves[0].target_rad
    data = copy.deepcopy(data)
    data["simulation"]["start_deg"] = [round(math.degrees(a), 9) for a in target]
    return data
