"""Which planned runs will subtract the empty run the drive-gain calibration subtracted (for ``evaluation.design``).

A run reuses the robot's stored baseline only when its plan has the baseline's fingerprint
(``session.baseline.require_valid``); any other plan records an empty run of its own. Where the stored calibration
subtracted that stored baseline too (its own empty run became it, or it reused it), a run that reuses it shares its
noise with the calibration, and its σ carries the correlation of the two (``shared_baseline``, ``Gains.shared_baseline``).
``plan --target-std`` has to predict that σ, so it needs to know, per candidate, whether its run is such a run.
"""

from __future__ import annotations

from dataclasses import dataclass

from payload_agent.configuration.config import Config


@dataclass(frozen=True)
class SharedBaseline:
    """The stored empty-flange baseline the stored calibration subtracted (``session.target.shared_baseline``)."""

    plan_fingerprint: str
    procedure: str  # its procedure's name and sweep speed: a cheap screen before a candidate's plan is made
    speed_percent: float

    def reused_by(self, run_config: Config) -> bool:
        """Whether a run with ``run_config`` (the config the run itself uses, its inertia part included) subtracts this
        baseline. Its age and the joints' temperatures, which the run also checks, are taken to pass."""
        from payload_agent.motion.planner import make_plan

        pc = run_config.procedure
        if pc.name != self.procedure or float(pc.speed_percent) != float(self.speed_percent):
            return False
        try:
            return make_plan(run_config).fingerprint() == self.plan_fingerprint
        except ValueError:
            return False


def reusing_run_mount(config: Config, plan, start_q) -> "np.ndarray":
    """Where the loaded run of a run that reuses the stored baseline starts, in the plan's own joint turns: it records
    no empty run, so it starts where the robot stands (``start_q``), and the run's moves are the plan's turned by whole
    turns to start near there (``turned_to``). The rest of a cable's spring in the plan's wrist term
    (``planned_terms.wrist_model``)."""
    import numpy as np

    from payload_agent.motion.planner import turned_to

    start = np.asarray(start_q, float)
    shift = np.asarray(turned_to(config, plan, start).moves[0].target_rad) - np.asarray(plan.moves[0].target_rad)
    return start - shift


__all__ = ["SharedBaseline", "reusing_run_mount"]
