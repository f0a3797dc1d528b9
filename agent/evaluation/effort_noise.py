"""White effort noise per joint measured in recorded sweeps (the stored baseline), for ``plan --target-std``.

A joint's effort noise depends on whether it moves: a UR's drives are 2-5x noisier in motion than standing
(docs/sources.md, "Effort noise of the simulated UR5e"). In a joint-2 sweep joint 3 stands but carries the
payload's torque, and its rows weigh in the fit by its standing noise, so the two are measured apart.
"""

from __future__ import annotations

import math

import numpy as np


def measured_effort_std(sweeps, moving: bool | None = None) -> tuple[float, ...]:
    """Each joint's white effort noise (N·m) in recorded sweeps: the second differences of its effort inside the
    constant-speed windows, std/√6, median over sweeps (nan where none). ``moving``: True only the sweeping joint
    of each sweep, False only the standing ones, None every joint of every sweep."""
    from payload_agent.analysis.delta import window_of
    from payload_agent.errors import DataError
    from payload_agent.evaluation.quality import noise_estimate

    per_joint: list[list[float]] = [[] for _ in range(6)]
    for s in sweeps.values():
        try:
            win = window_of(s)
        except DataError:
            continue
        e = np.asarray(s.effort_nm, float)[win.slice]
        if len(e) < 10:
            continue
        for j in range(6):
            if moving is None or (j == s.key.joint - 1) == moving:
                per_joint[j].append(noise_estimate(e[:, j]))
    return tuple(float(np.median(v)) if v else float("nan") for v in per_joint)


def moving_and_standing_std(sweeps) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(each joint's noise while it sweeps, while it stands): where a joint never did one of them in the
    recording, the other, and where it did neither, every sweep's median."""
    both = measured_effort_std(sweeps)
    moving, standing = measured_effort_std(sweeps, True), measured_effort_std(sweeps, False)
    moving = tuple(m if math.isfinite(m) else (s if math.isfinite(s) else b) for m, s, b in zip(moving, standing, both))
    standing = tuple(s if math.isfinite(s) else m for s, m in zip(standing, moving))
    return moving, standing
