"""The drive-gain calibration's own response to each DH-length error, measured where the calibration is made.

A DH length off by δp_k changes the reference payload's torque on the calibration's own sweeps by
∂Y/∂p_k·θ_ref·δp_k (as ``general.length_derivatives``: positions are linear in the lengths); the calibration's
fit (``gain_scales`` then ``zero_offsets.refit``, as ``calibration.fit_from_sweeps`` makes it) turns that into a
change of its gain scales and joint zeros. This module adds that torque for one length at a time, at a step small
against any noise and large against rounding, refits exactly as the calibration fits and stores the change per
metre (``solvers.length_response.LengthResponse``): what a run scaled and corrected with these gains and zeros
carries of the same length error, whatever procedure it sweeps (the older rule let the run's sweeps stand in for
the calibration's, docs/benchmarks.md session 15).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import general
from payload_agent.solvers.length_response import LengthResponse
from payload_agent.solvers.regressor import payload_regressor
from payload_agent.types import SweepKey

STEP_M = 1e-5  # 10 µm: torque changes ~1e-4 N·m (5 kg), far below the noise that sets the fit's weights

# the calibration's fit of (deltas) -> (scale per joint, zero shift per joint in rad), as fit_from_sweeps makes it
Fit = Callable[[Mapping[SweepKey, DeltaSweep]], tuple[np.ndarray, np.ndarray]]


def _payload_torque(d: DeltaSweep, kin: Kinematics, theta: np.ndarray) -> np.ndarray:
    """(n, 6): the payload θ's torque on every joint along the sweep (gravity and the centripetal part)."""
    qd = np.zeros_like(d.q)
    qd[:, d.moving] = d.speed_rad_s
    return payload_regressor(kin, d.q, qd, np.zeros_like(d.q), inertia=False) @ theta


def measure(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, theta_ref: Sequence[float], fit: Fit,
            at: tuple[np.ndarray, np.ndarray]) -> LengthResponse:
    """Per length of ``general.length_parameters(kin)``: the calibration's relative scale change and zero change
    per metre. ``fit``: the calibration's fit of a set of deltas; ``at``: its result on ``deltas`` themselves."""
    theta = np.asarray(theta_ref, float)
    scale0, zero0 = (np.asarray(v, float) for v in at)
    base = {k: _payload_torque(d, kin, theta) for k, d in deltas.items()}
    params = general.length_parameters(kin)
    scales, zeros = [], []
    for row, which in params:
        moved = general.perturbed(kin, row, which, STEP_M)
        shifted = {k: replace(d, dtau=d.dtau + _payload_torque(d, moved, theta) - base[k]) for k, d in deltas.items()}
        scale, zero = fit(shifted)
        scales.append(tuple(float(v) for v in (scale - scale0) / scale0 / STEP_M))
        zeros.append(tuple(float(v) for v in (zero - zero0) / STEP_M))
    return LengthResponse(tuple(params), tuple(scales), tuple(zeros))


__all__ = ["STEP_M", "measure"]
