"""Quality check: a torque on the wrist that the payload's weight does not explain (a tool cable or hose).

A cable or hose from the forearm to the tool is a spring on joints 4–6. During every arm sweep
the wrist stands still, so the spring's torque is constant along the sweep, while the payload's
weight torque on the wrist changes with the link angle. The check fits the general model twice
on the same deltas (``systematics.offsets``): with the moving joint's friction offsets only, and
with one more constant offset per (pose, wrist joint). It fails when both hold:

- the wrist offsets are there: their Wald χ² exceeds the (1 − ``ALPHA``) quantile of χ²_k
  (k offsets), with the autocorrelation-robust covariance of the fit;
- they matter: allowing them moves the estimate by more than ``MASS_SHIFT_G`` or
  ``COG_SHIFT_MM`` (a small cable that moves nothing is no reason to refuse a result).

The reason names the likely cause and says how much the result depends on it. The check
returns a dict in the quality gate's format (``quality._check``); ``quality.evaluate`` runs it.
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.evaluation.systematics import offsets
from payload_agent.solvers.fitted import FittedModel
from payload_agent.types import SweepKey

NAME = "tool cable / hose on the wrist"
ALPHA = 1e-3  # false-alarm rate of the significance test alone
# the estimate moves by more than this (mass) or this (centre of mass) when the wrist offsets are
# allowed: below the 10 g / 5 mm a cable must not move a result unnoticed, above the shift that
# noise and the other effects of a real arm cause (a few g, benchmarks/hard.py)
MASS_SHIFT_G = 8.0
COG_SHIFT_MM = 4.0


def chi2_quantile(p: float, k: int) -> float:
    """The p quantile of χ² with k degrees of freedom: 2·P⁻¹(k/2, p) (scipy.special, far lighter to import
    than scipy.stats, which the agent's every run would otherwise pay for)."""
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(0.5 * k, p))


def _mass_cog(theta: np.ndarray) -> tuple[float, np.ndarray]:
    return float(theta[0]), np.asarray(theta[1:4]) / theta[0]


def check(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, gain_rel_std: Iterable[float] | None = None,
          alpha: float = ALPHA, mass_shift_g: float = MASS_SHIFT_G, cog_shift_mm: float = COG_SHIFT_MM,
          model: FittedModel | None = None) -> dict[str, Any]:
    """The check dict: ``value`` = the larger shift relative to its limit (> 1 with significant offsets fails).

    ``model``: the analysis' fitted model of these deltas; its offset fits are shared with the wrist term.
    """
    gain = None if gain_rel_std is None else list(gain_rel_std)
    try:
        base = offsets.fit_offsets(deltas, kin, offsets.moving_joint, gain_rel_std=gain, model=model)
        wrist = offsets.fit_offsets(deltas, kin, offsets.moving_joint, offsets.wrist_joint, gain_rel_std=gain,
                                    model=model)
    except (DataError, np.linalg.LinAlgError) as exc:
        return {"check": NAME, "value": float("nan"), "limit": 1.0, "passed": True,
                "note": f"not evaluated: {exc}"}
    idx = [i for i, name in enumerate(wrist.labels) if name not in set(base.labels)]
    b = wrist.offsets_nm[idx]
    cov_b = wrist.offsets_cov[np.ix_(idx, idx)]
    labels = [wrist.labels[i] for i in idx]
    k = len(b)
    if k == 0:
        return {"check": NAME, "value": 0.0, "limit": 1.0, "passed": True, "note": "no still wrist joint rows"}
    chi2 = float(b @ np.linalg.lstsq(cov_b, b, rcond=None)[0])
    chi2_limit = chi2_quantile(1.0 - alpha, k)
    m0, c0 = _mass_cog(base.theta)
    m1, c1 = _mass_cog(wrist.theta)
    dm_g = 1000.0 * (m1 - m0)
    dc_mm = 1000.0 * float(np.linalg.norm(c1 - c0))
    shift = max(abs(dm_g) / mass_shift_g, dc_mm / cog_shift_mm)
    significant = chi2 > chi2_limit
    passed = not (significant and shift > 1.0)
    worst = int(np.argmax(np.abs(b)))
    out = {"check": NAME, "value": float(shift), "limit": 1.0, "passed": bool(passed),
           "chi2": chi2, "chi2_limit": chi2_limit, "dof": k, "mass_shift_g": dm_g, "cog_shift_mm": dc_mm,
           "largest_offset": {"group": labels[worst], "torque_nm": float(b[worst])},
           "estimate_with_offsets": {"mass_kg": m1, "cog_mm": (1000.0 * c1).tolist()}}
    if not passed:
        out["reason"] = (f"the wrist joints carry a constant torque the payload's weight does not explain "
                         f"(up to {abs(b[worst]):.3f} N·m on {labels[worst]}; χ² {chi2:.0f} > {chi2_limit:.0f}); "
                         f"allowing for it moves the result by {dm_g:+.1f} g and {dc_mm:.1f} mm. Likely a tool "
                         "cable or hose pulling on the wrist: route it so it does not strain the wrist "
                         "(or remove it) and run again")
    return out
