"""The candidate of ``plan --target-std`` that makes the stored baseline's plan exactly, beside the grid.

A run reuses the stored empty-flange baseline only when its plan has the baseline's fingerprint
(``session.baseline.require_valid``): then it records no empty run of its own, and where the stored calibration
subtracted that baseline too (its empty run became it), its σ is 14–20 % tighter on sim-ec66 (the shared-baseline
term, ``planned_baseline``; docs/benchmarks.md, "Session 19: the plan's shared-baseline term"). The grid
(``evaluation.candidates``) never held that plan: a calibration runs at the YAML's travel speed and acceleration and
its own speed, procedure and range. So the plan adds it, from the keys the baseline recorded
(``BaselineInfo.procedure_keys``: the config as the session used it, a ``calibrate`` override included), its inertia
part as recorded, and only when the candidate's run makes that very plan (the fingerprint, under today's YAML).
"""

from __future__ import annotations

import dataclasses

from payload_agent.configuration.config import Config
from payload_agent.errors import BaselineError, ConfigError
from payload_agent.evaluation.candidates import CONFIGURED, Candidate, candidates_for
from payload_agent.recording.state import RobotState


def stored_candidate(config: Config) -> Candidate | None:
    """The candidate whose run reuses the stored baseline; None without one, without its recorded keys (stored before
    they were), or when no candidate makes its plan under ``config`` (another base angle, direction rule or DH)."""
    from payload_agent.evaluation.design import run_config
    from payload_agent.motion.planner import make_plan
    from payload_agent.session.baseline import load_baseline

    try:
        stored = load_baseline(RobotState.for_config(config))
    except BaselineError:
        return None
    keys = None if stored is None else stored.procedure_keys
    if not keys:
        return None
    try:
        lo, hi = (float(v) for v in keys["sweep_deg"])
        inertia = keys.get("inertia") or None
        name = str(keys["name"])
        c = Candidate(float(keys["speed_percent"]), float(keys["travel_speed_percent"]), lo, hi, 1,
                      float(keys["accel_percent"]), "" if name == config.procedure.name else name,
                      CONFIGURED if inertia == config.procedure.inertia else inertia, stored_baseline=True)
        fingerprint = make_plan(run_config(config, c)).fingerprint()
    except (KeyError, TypeError, ValueError, ConfigError):
        return None
    return c if fingerprint == stored.plan_fingerprint else None


def grid_for(config: Config) -> list[Candidate]:
    """``candidates_for(config)`` and the stored baseline's plan (``stored_candidate``), once: where the grid holds the
    same plan already, that row is marked as it."""
    grid, stored = candidates_for(config), stored_candidate(config)
    if stored is None:
        return grid
    same = dataclasses.replace(stored, stored_baseline=False)
    if same in grid:
        return [stored if c == same else c for c in grid]
    return [*grid, stored]
