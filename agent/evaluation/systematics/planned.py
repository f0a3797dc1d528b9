"""What the systematic terms will add to a planned procedure's σ, before it moves (``evaluation.design``).

Only the terms that can be predicted without the run's data: the joint zeros and the residual friction with
its declared change (the run measures the change; the prior is the expectation of what it reports). The
run-time terms are in ``evaluation.systematics``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.configuration.config import JointSystematicsConfig
from payload_agent.evaluation.systematics import compliance, offsets
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import general


def planned_covariance(sweeps: Sequence[DeltaSweep], kin: Kinematics, decl: JointSystematicsConfig,
                       theta: np.ndarray, weights: np.ndarray, friction_level_nm: Mapping[int, float] | None = None
                       ) -> np.ndarray:
    """The terms that can be predicted before moving, for a planned procedure (``evaluation.design``).

    ``sweeps``: the plan's synthetic sweeps at the samples the analysis will use (Δτ unused), ``theta``
    a nominal payload, ``weights`` the fit's row weights (1/σ², in ``build_groups`` order). Predicted:
    the joint zeros (θ̂ = (YᵀWY)⁻¹YᵀW·Y(q + z)θ, by a finite step; their covariance as ``decl`` gives it, measured
    and correlated where a calibration measured them, ``evaluation.zero_offsets``) and the residual friction with the
    declared change only (``friction_change_std`` × ``friction_level_nm`` per moving joint, e.g. what the
    stored baseline shows): the run measures the change and reports the posterior, whose expectation
    before the run is this prior. Not predictable: the stiffness term
    (it needs the arm's own torques). The terms the run sizes from its data (the wrist torques as a tool
    cable's spring, the residual friction as measured) are ``evaluation.planned_terms``'.
    """
    sweeps = list(sweeps)
    groups = general.build_groups(sweeps, kin)
    Y = np.vstack([g.Y for g in groups])
    w = np.asarray(weights, float)
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)
    zstd = np.broadcast_to(np.asarray(decl.zero_offset_std_rad, float), (6,))
    S = np.zeros((4, 6))
    row_joint = np.concatenate([np.full(len(g.y), g.joint) for g in groups])
    coupling = np.zeros((6, 6)) if decl.zero_gain_coupling is None else np.asarray(decl.zero_gain_coupling, float)
    for j in np.flatnonzero(zstd > 0):
        shifted = [replace(d, q=d.q + np.eye(6)[j] * compliance.ZERO_STEP_RAD) for d in sweeps]
        Y1 = np.vstack([g.Y for g in general.build_groups(shifted, kin)])
        # the data at link angles shifted by h against the model at the reported ones: as the model's angles shifted
        # by −h (``compliance.sensitivities``), so the drive gains coupled to the zero change the effort by −h·c
        change = (Y1 - Y) @ theta - compliance.ZERO_STEP_RAD * coupling[j, row_joint] * (Y @ theta)
        S[:, j] = inv @ (Y.T @ (w * change)) / compliance.ZERO_STEP_RAD
    # the zeros' covariance: declared independent, or as a calibration measured them (correlated)
    cov = S @ compliance.zero_covariance(zstd, decl.zero_offset_corr) @ S.T
    rel = float(decl.friction_asymmetry_std) * float(decl.friction_change_std)
    if rel > 0 and friction_level_nm:
        s = offsets.offset_sensitivities(sweeps, groups, w, inv, lambda g, d: (
            str(g.joint) if g.joint == d.moving and d.key.direction == "both" and g.joint in friction_level_nm
            else None))
        for j, v in s.items():
            cov += (rel * friction_level_nm[int(j)]) ** 2 * np.outer(v, v)
    return cov


__all__ = ["planned_covariance"]
