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

# a candidate is predicted again without its length term only when the root of its expected variance less that term
# is within this factor of the target (the prediction proper is a median over draws, close to that root)
SCREEN = 1.15


def kept_out_by_lengths(config: Config, choice: design.Choice, noise: design.NoiseModel, theta: Sequence[float],
                        mass_std_g: float, cog_std_mm: float, start_q=None
                        ) -> tuple[design.Prediction, design.Prediction] | None:
    """The fastest usable candidate faster than the chosen one (any, when none was chosen) that misses the target
    with its DH-length term and meets it without (``design.Prediction.meets``): (its prediction, the one without
    the term); None when there is none, or the plan carries no length term."""
    if noise.length_std_m <= 0:
        return None
    theta = np.asarray(theta, float)
    without = dataclasses.replace(noise, length_std_m=0.0)
    limit = float("inf") if choice.best is None else choice.best.robot_time_s
    faster = [p for p in choice.table if p.usable and p.robot_time_s < limit and not p.meets(mass_std_g, cog_std_mm)]
    lengths: dict[tuple, tuple[float, float]] = {}  # the term depends on the procedure and the range only
    for p in sorted(faster, key=lambda p: p.robot_time_s):
        c = p.candidate
        key = (c.procedure, c.sweep_from_deg, c.sweep_to_deg)
        if key not in lengths:
            terms, _ = design.covariance_terms(design.with_candidate(config, c), design.plan_for(config, c), noise,
                                               theta)
            lengths[key] = _sigmas(theta, terms["lengths"])
        m, cm = lengths[key]
        if (p.mass_rms_std_g ** 2 - m ** 2 > (SCREEN * mass_std_g) ** 2
                or p.cog_rms_std_mm ** 2 - cm ** 2 > (SCREEN * cog_std_mm) ** 2):
            continue
        # the safety gate passed it already (usable): the same candidate, the same plan
        q = design.predict(config, c, without, theta, check_safety=False, start_q=start_q)
        if q.meets(mass_std_g, cog_std_mm):
            return p, q
    return None


def _sigmas(theta: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """(σ mass g, σ centre of mass mm, largest axis) of one term: taken off the candidate's largest-axis σ it gives
    a lower bound of that σ without the term (the screen must not drop a candidate that would meet the target)."""
    from payload_agent.solvers.wls import cog_with_covariance

    _, cov_c = cog_with_covariance(theta, cov)
    return 1000.0 * math.sqrt(max(cov[0, 0], 0.0)), 1000.0 * math.sqrt(max(float(np.max(np.diag(cov_c))), 0.0))


def calibration_advice(config: Config, choice: design.Choice, noise: design.NoiseModel, theta: Sequence[float],
                       mass_std_g: float, cog_std_mm: float, start_q=None) -> str:
    """A line for ``plan --target-std`` when a faster candidate misses the target only by its DH-length term and the
    stored calibration swept another procedure than that candidate's; "" otherwise (no calibration stored, or one
    that does not record its procedure, or no such candidate, or one on the calibration's own procedure)."""
    from payload_agent.evaluation.calibration import effective_calibration

    cal = effective_calibration(config)
    if cal is None or cal.procedure is None:
        return ""
    found = kept_out_by_lengths(config, choice, noise, theta, mass_std_g, cog_std_mm, start_q)
    if found is None:
        return ""
    p, q = found
    name = p.candidate.procedure or config.procedure.name
    if load_procedure(name).fingerprint == cal.procedure.fingerprint:
        return ""
    return (f"{p.candidate.describe()} ({p.robot_time_s:.0f} s) misses the target only by its DH-length term: "
            f"σ {p.mass_std_g:.2f} g / {p.cog_std_mm:.2f} mm, {q.mass_std_g:.2f} g / {q.cog_std_mm:.2f} mm without "
            f"it. The stored calibration swept {cal.procedure.describe()}; a calibration on {name} absorbs more of "
            f"the lengths for a run on {name} (how much is known only after it): `payload-agent calibrate --robot "
            f"{config.source} --known-mass KG --known-cog X,Y,Z --procedure {name}`, then plan again.")
