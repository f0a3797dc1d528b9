"""The candidate procedures ``plan --target-std`` predicts: sweep speed, travel speed, acceleration, sweep range,
repetitions and the procedure (the configured one, or a bundled joint-2-only one), as a grid.

The bundled procedures (procedures/j2_pair.yaml, j2_triple.yaml, j2_quarter.yaml) sweep joint 2 only in two or
three tool orientations: they carry the payload's weight on the longest lever (links 2 and 3 collinear) and need
no 90° joint-2 travel to a joint-3 sweep's start. j2_quarter's two orientations are one quarter wrist turn apart
and its first holds the tool z up, off the payload's lever, so the flange-offset length hardly moves the mass:
on a calibrated UR5e that is what takes 2 g / 1 mm under 15 s (docs/benchmarks.md, "Session 14: 15 s on
sim-ur5e"). ``evaluation.design`` predicts each candidate's σ.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Iterable

from payload_agent.configuration.config import Config

# sweep speeds above safety.max_speed_percent are refused by the gate, as ``plan`` would refuse them
SPEEDS_PERCENT = (3.0, 5.0, 7.0, 10.0, 12.0, 15.0, 20.0, 22.5, 25.0)
TRAVEL_PERCENT = (25.0,)  # capped by safety.max_speed_percent in ``candidates_for``
# long ranges pay where the wrist-torque term binds the centre of mass: the wrist offsets of a pose are
# separable from m·c only through the change of the wrist's gravity torque along the sweep (issue 22)
RANGES_DEG = ((0.0, 15.0), (0.0, 20.0), (0.0, 30.0), (0.0, 40.0), (0.0, 55.0), (0.0, 70.0), (0.0, 90.0))
ACCELS_PERCENT = (40.0, 100.0)
# The product's grid runs each procedure once: a run has no repetition key, so a chosen "×2" could not be run
# as chosen (issue 22); ``candidates(reps=...)`` still predicts repetitions for the benchmarks.
REPETITIONS = (1,)
# "" = the configured procedure; the others are bundled (procedures/*.yaml)
PROCEDURES = ("", "j2_pair", "j2_triple", "j2_quarter")
# ``Candidate.inertia``: the robot YAML's inertia part (``procedure.inertia``) as it is
CONFIGURED = "as configured"


@dataclass(frozen=True)
class Candidate:
    speed_percent: float
    travel_percent: float
    sweep_from_deg: float
    sweep_to_deg: float
    repetitions: int = 1
    accel_percent: float = 20.0
    procedure: str = ""  # procedure name or file; "" = the configured one
    # the run's inertia part (``procedure.inertia``: a wrist procedure's name, None off); ``CONFIGURED``: the YAML's.
    # Only the stored baseline's plan sets it (``session.stored_candidate``): its run must make that plan exactly
    inertia: str | None = CONFIGURED
    # the stored baseline's plan: its run reuses the stored empty run (the calibration's, when it recorded it)
    stored_baseline: bool = False

    def describe(self) -> str:
        reps = f" ×{self.repetitions}" if self.repetitions > 1 else ""
        proc = f"{self.procedure}: " if self.procedure else ""
        inertia = ("" if self.inertia == CONFIGURED else
                   ", inertia part off" if self.inertia is None else f", inertia part {self.inertia}")
        stored = ", the stored baseline's plan" if self.stored_baseline else ""
        return (f"{proc}sweep {self.speed_percent:g} %, travel {self.travel_percent:g} %, "
                f"accel {self.accel_percent:g} %, {self.sweep_from_deg:g}–{self.sweep_to_deg:g}°{reps}{inertia}{stored}")


def candidates(speeds: Iterable[float] = SPEEDS_PERCENT, travels: Iterable[float] = TRAVEL_PERCENT,
               ranges: Iterable[tuple[float, float]] = RANGES_DEG, reps: Iterable[int] = REPETITIONS,
               accels: Iterable[float] = ACCELS_PERCENT, procedures: Iterable[str] = PROCEDURES) -> list[Candidate]:
    return [Candidate(s, t, lo, hi, r, a, p)
            for p, s, t, (lo, hi), r, a in itertools.product(procedures, speeds, travels, ranges, reps, accels)]


def candidates_for(config: Config) -> list[Candidate]:
    """The default grid for a robot: travel at most its speed cap, the configured procedure and the
    bundled ones (without a duplicate of the configured one)."""
    travel = tuple(sorted({min(t, config.safety.max_speed_percent) for t in TRAVEL_PERCENT}))
    procs = tuple(p for p in PROCEDURES if not p or p != config.procedure.name)
    return candidates(travels=travel, procedures=procs)
