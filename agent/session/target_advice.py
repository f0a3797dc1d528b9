"""`plan --target-std`'s advice on the drive-gain calibration: a faster candidate that only its DH-length term keeps
from the target, and the calibration that could take it in.

A calibration absorbs into its gains and zeros part of the arm's DH-length errors; how much, for a tool run,
depends on where the calibration's sweeps lie (its measured ``length_response``): for a run on the procedure the
calibration swept, nearly all of it; for another procedure, far less (docs/benchmarks.md, "Session 15: the length
term after a calibration on another procedure" and "Session 16: calibrating on the run's procedure"). The plan
can tell which faster candidate misses the target only by that term (its σ predicted again without it), but
not how much of the term a calibration on that candidate's procedure would leave: that needs the other
calibration's own response, measured on its own sweeps. So the advice names the candidate and the command, and
promises nothing about the result; the user plans again after the calibration.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.configuration.procedure import load_procedure
from payload_agent.evaluation import design

# a candidate is predicted again without its length term (the slow part) only when the root of its expected mass
# variance less that term is within this factor of the target mass σ: a screen, not a bound (the prediction proper is
# a median over draws of the wrist term; for the mass it sits within a few % of that root on the plan_budget tables
# of docs/benchmarks.md, for the centre of mass it can be far below it, 0.28 against 0.38 mm on j2_pair, so the
# centre of mass is not screened)
SCREEN = 1.15


def kept_out_by_lengths(config: Config, choice: design.Choice, noise: design.NoiseModel, theta: Sequence[float],
                        mass_std_g: float, cog_std_mm: float, start_q=None, from_rest: bool = False
                        ) -> list[tuple[design.Prediction, design.Prediction]]:
    """Per procedure, the fastest usable candidate faster than the chosen one (any, when none was chosen) that misses
    the target with its DH-length term and meets it without (``design.Prediction.meets``): (its prediction, the one
    without the term), fastest first; [] when there is none, or the plan carries no length term."""
    if noise.length_std_m <= 0:
        return []
    theta = np.asarray(theta, float)
    without = dataclasses.replace(noise, length_std_m=0.0)
    limit = float("inf") if choice.best is None else choice.best.robot_time_s
    faster = [p for p in choice.table if p.usable and p.robot_time_s < limit and not p.meets(mass_std_g, cog_std_mm)]
    lengths: dict[tuple, float] = {}  # its mass σ, g: the term depends on the procedure and the range only
    found: dict[str, tuple[design.Prediction, design.Prediction]] = {}
    for p in sorted(faster, key=lambda p: p.robot_time_s):
        c = p.candidate
        if c.procedure in found:
            continue
        key = (c.procedure, c.sweep_from_deg, c.sweep_to_deg)
        if key not in lengths:
            terms, _ = design.covariance_terms(design.with_candidate(config, c), design.plan_for(config, c), noise,
                                               theta)
            lengths[key] = 1000.0 * math.sqrt(max(float(terms["lengths"][0, 0]), 0.0))
        if p.mass_rms_std_g ** 2 - lengths[key] ** 2 > (SCREEN * mass_std_g) ** 2:
            continue
        # the safety gate passed it already (usable): the same candidate, the same plan
        q = design.predict(config, c, without, theta, check_safety=False, start_q=start_q, from_rest=from_rest)
        if q.meets(mass_std_g, cog_std_mm):
            found[c.procedure] = (p, q)
    return list(found.values())


def calibration_advice(config: Config, choice: design.Choice, noise: design.NoiseModel, theta: Sequence[float],
                       mass_std_g: float, cog_std_mm: float, start_q=None, from_rest: bool = False) -> str:
    """Lines for ``plan --target-std`` naming, per procedure other than the one the stored calibration swept, the
    fastest faster candidate that misses the target only by its DH-length term, with the calibration on that
    procedure; "" when there is none, or no calibration stored, or one that does not record its procedure."""
    from payload_agent.evaluation.calibration import effective_calibration

    cal = effective_calibration(config)
    if cal is None or cal.procedure is None:
        return ""
    lines = []
    for p, q in kept_out_by_lengths(config, choice, noise, theta, mass_std_g, cog_std_mm, start_q, from_rest):
        name = p.candidate.procedure or config.procedure.name
        if load_procedure(name).fingerprint != cal.procedure.fingerprint:
            lines.append(f"  {p.candidate.describe()} ({p.robot_time_s:.0f} s): σ {p.mass_std_g:.2f} g / "
                         f"{p.cog_std_mm:.2f} mm, {q.mass_std_g:.2f} g / {q.cog_std_mm:.2f} mm without it; "
                         f"`payload-agent calibrate --robot {config.source} --known-mass KG --known-cog X,Y,Z "
                         f"--procedure {name}`")
    if not lines:
        return ""
    return "\n".join([f"Faster candidates that miss the target only by their DH-length term (the stored calibration "
                      f"swept {cal.procedure.describe()}; one on a candidate's own procedure absorbs more of the "
                      f"lengths for it, how much is known only after it: plan again then):", *lines])


def parked_what_if(config: Config, c, noise: design.NoiseModel, theta) -> design.Prediction:
    """The candidate ``c`` as its run would be after ``calibrate --park`` on its own plan: the arm at its first pose
    (our resting pose, no approach), the run reusing the calibration's empty run (the shared-baseline term), and the
    calibration absorbing its whole DH-length term (one on the procedure the run sweeps absorbs nearly all of it,
    docs/benchmarks.md session 16). The drive gains' uncertainty stays the one the plan has now: the new calibration's
    is known only after it. A what-if to screen by, not the prediction the plan makes after that calibration."""
    from payload_agent.evaluation.planned_baseline import SharedBaseline

    own = dataclasses.replace(c, inertia=None, stored_baseline=True)  # `calibrate --procedure` leaves the part out
    cfg = design.run_config(config, own)
    plan = design.plan_for(config, own)
    shared = SharedBaseline(plan.fingerprint(), cfg.procedure.name, float(c.speed_percent))
    first = plan.moves[0].target_rad
    return design.predict(config, own, dataclasses.replace(noise, length_std_m=0.0, shared_baseline=shared), theta,
                          start_q=first, from_rest=True)


def park_advice(config: Config, choice: design.Choice, noise: design.NoiseModel, theta: Sequence[float],
                mass_std_g: float, cog_std_mm: float) -> str:
    """Lines for ``plan --target-std`` naming the fastest candidate whose procedure alone is faster than the chosen
    row's robot time (its approach counted; any, when none meets the target) and which, calibrated on with ``--park``,
    would meet the target in the what-if of ``parked_what_if``: the ``calibrate`` command with its keys and
    ``--park``; "" when none is found or the chosen row is the stored plan already (the calibration's own). Nothing is
    promised: plan again after it."""
    from payload_agent.errors import PayloadAgentError
    from payload_agent.evaluation.candidates import candidates_for
    from payload_agent.motion.planner import robot_time_s

    best = choice.best
    if best is not None and best.candidate.stored_baseline:
        return ""
    limit = float("inf") if best is None else best.robot_time_s
    theta = np.asarray(theta, float)
    groups: dict = {}  # the candidates alike but for their sweep speed, each with its procedure's robot time
    for c in candidates_for(config):
        try:
            t = robot_time_s(design.plan_for(config, c))
        except (PayloadAgentError, ValueError):
            continue
        if c.repetitions == 1 and t < limit:
            groups.setdefault(dataclasses.replace(c, speed_percent=0.0), []).append((t, c))
    # a screen, to keep `plan` quick: a group whose slowest sweep (the most samples) misses is left out whole
    what_if: dict = {}  # candidate -> its ``parked_what_if``, each predicted once

    def predicted(c):
        if c not in what_if:
            what_if[c] = parked_what_if(config, c, noise, theta)
        return what_if[c]

    kept = [tc for members in groups.values() for tc in members
            if predicted(max(members, key=lambda m: m[0])[1]).meets(mass_std_g, cog_std_mm)]
    for t, c in sorted(kept, key=lambda tc: tc[0]):
        q = predicted(c)
        if not q.meets(mass_std_g, cog_std_mm):
            continue
        now = next((p for p in choice.table if p.candidate == c), None)
        name = c.procedure or config.procedure.name
        return "\n".join([
            ("Faster" if best is not None else "Within the target, perhaps,")
            + f" with a calibration on its own plan that parks the arm at its first pose: {c.describe()}, "
            f"{t:.1f} s of robot time with no approach"
            + ("" if now is None or not now.usable else
               f" (now: {now.robot_time_s:.0f} s with the approach, σ {now.mass_std_g:.2f} g / {now.cog_std_mm:.2f} mm, "
               f"P over {100 * now.p_over(mass_std_g, cog_std_mm):.0f} %)") + ":",
            f"  payload-agent calibrate --robot {config.source} --known-mass KG --known-cog X,Y,Z --procedure {name} "
            f"--speed-percent {c.speed_percent:g} --sweep-deg {c.sweep_from_deg:g},{c.sweep_to_deg:g} "
            f"--travel-speed-percent {c.travel_percent:g} --accel-percent {c.accel_percent:g} --park",
            f"  then mount the tool where it parks and plan again: `plan --target-std` offers that plan, whose run starts "
            f"there and reuses the calibration's empty run. Its σ is known only after the calibration (if it took the "
            f"whole DH-length term, with the gains' uncertainty as now: {q.mass_std_g:.2f} g / {q.cog_std_mm:.2f} mm, "
            f"P over {100 * q.p_over(mass_std_g, cog_std_mm):.0f} %)."])
    return ""
