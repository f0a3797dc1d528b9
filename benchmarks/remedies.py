"""The benchmark method general-bi-cal-comp: general-bi-cal with the remedies for a real arm's effects.

What the agent itself does (``payload-agent run`` / ``solve`` / ``calibrate``), through its own recipe
``payload_agent.evaluation.systematics``: the declared joint stiffness is compensated in the tool run,
the empty-flange baseline and the calibration reference run alike; the declared stiffness and
zero-offset uncertainties, the friction the two-direction average leaves (declared direction asymmetry ×
the friction change measured between the runs) and constant wrist torques sized from the data go into σ
and into the quality gate's pose comparison; the gate's tool-cable check does the rest.

The declared values are what a correctly configured agent knows about the simulated arm
(``benchmarks.hard.Declared``), as the robot YAML's ``robot.kinematics.stiffness_nm_per_rad``,
``stiffness_uncertainty_percent``, ``zero_offset_uncertainty_deg``, ``robot.friction_asymmetry_percent`` and
``robot.friction_change_percent`` would say; the realistic arm has none of these effects and declares none.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmarks.cases import COMP, _calibrate, _gate, theta_reference


def declaration(declared):
    """``benchmarks.hard.Declared`` (or None: nothing) as the agent's ``JointSystematicsConfig``."""
    from payload_agent.configuration.config import JointSystematicsConfig
    from payload_agent.evaluation import systematics

    if declared is None:
        return systematics.RIGID
    return JointSystematicsConfig(declared.stiffness_nm_per_rad, declared.stiffness_rel_std,
                                  (declared.zero_offset_std_rad,) * 6, declared.friction_asymmetry_std,
                                  declared.friction_change_std)


def scaled(sweeps: dict, scale: np.ndarray) -> dict:
    """Sweeps with their effort at the calibrated gains (what the agent loads after a calibration)."""
    return {k: dataclasses.replace(s, effort_nm=np.asarray(s.effort_nm) * scale) for k, s in sweeps.items()}


def comp_estimate(loaded: dict, empty: dict, ref: dict, declared, config, unfitted_std: float, kin_kw: dict):
    """(Estimate, gate columns) of general-bi-cal-comp on one case's recorded sweeps."""
    from payload_agent.evaluation import systematics
    from payload_agent.solvers import general

    kin = config.robot.kinematics
    decl = declaration(declared)
    scale, gain_rel_std, fitted = _calibrate(ref, empty, config, unfitted_std, decl)
    kw = dict(kin_kw, gain_rel_std=list(gain_rel_std), gain_reference=(theta_reference(), fitted))
    prepared = systematics.prepare(scaled(loaded, scale), scaled(empty, scale), decl)
    est = general.solve(prepared.deltas, kin, name=COMP, **kw)
    syst = systematics.evaluate(prepared, kin, decl, kw["gain_rel_std"])
    est = syst.apply(est)
    return est, _gate(prepared.deltas, kin, est, systematics=syst, **kw)


__all__ = ["comp_estimate", "declaration"]
