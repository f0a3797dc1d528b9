"""Where the samples of a planned procedure lie, as the run's analysis will use them (for ``evaluation.design``).

``planned_sweeps`` places every sweep's constant-speed samples where the segmenter will find them (the commanded
profile's cruise interval, ``SweepCommand.cruise_interval``, sampled at the controller's period);
``too_few_samples`` says when a candidate's sweeps could hold too few of them for the quality gate.
"""

from __future__ import annotations

import numpy as np

from payload_agent.motion.planner import Plan


def planned_sweeps(plan: Plan, period_s: float):
    """Synthetic combined sweeps (``DeltaSweep``, Δτ = 0) at the samples the analysis will use."""
    from payload_agent.analysis.delta import DeltaSweep
    from payload_agent.analysis.segmenter import sweep_commands
    from payload_agent.types import SweepKey

    out = []
    for key, cmd in sweep_commands(plan.moves).items():
        if key.direction == "down":
            continue
        lo, hi = cmd.cruise_interval()
        speed = abs(float(cmd.speed_rad_s))
        n = max(int((hi - lo) / max(speed, 1e-9) / period_s), 2)
        q = np.tile(np.asarray(cmd.start_rad, float), (n, 1))
        q[:, cmd.joint] = np.linspace(lo, hi, n)
        both = any(k.direction == "down" and (k.pose, k.joint) == (key.pose, key.joint) for k in sweep_commands(plan.moves))
        direction = "both" if both else key.direction
        out.append(DeltaSweep(SweepKey(key.pose, key.joint, direction, key.speed_percent), q, np.zeros((n, 6)), speed))
    return out


def too_few_samples(plan: Plan, period_s: float) -> tuple[str, ...]:
    """Why the run could be refused for too few constant-speed samples in a sweep at ``period_s`` (the sample
    density the run will have), or nothing. The quality gate needs ``quality.MIN_SWEEP_SAMPLES`` per combined
    sweep, and the segmenter may keep as little as ``segmenter.MIN_VERIFIED_FRACTION`` of the planned cruise
    interval where the data do not confirm a constant speed (a stream timed on receipt, with gaps): measured on
    sim-ur5e-modbus, a j2_pair 15 %, 0–20° planned at 67 samples per sweep kept 37-44, and the gate refused
    every run. So a candidate needs the gate's count in that fraction of its planned samples."""
    from payload_agent.analysis.segmenter import MIN_VERIFIED_FRACTION
    from payload_agent.evaluation.quality import MIN_SWEEP_SAMPLES

    fewest = min(planned_sweeps(plan, period_s), key=lambda d: len(d.q), default=None)
    if fewest is None or MIN_VERIFIED_FRACTION * len(fewest.q) >= MIN_SWEEP_SAMPLES:
        return ()
    return (f"{fewest.key.name}: about {len(fewest.q)} constant-speed samples at {1.0 / period_s:.0f} per s; the "
            f"quality gate needs {MIN_SWEEP_SAMPLES} in the {MIN_VERIFIED_FRACTION:g} of them the segmentation may "
            f"keep: a slower sweep or a wider range",)


__all__ = ["planned_sweeps", "too_few_samples"]
