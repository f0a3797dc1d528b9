"""The benchmark method general-bi-cal-comp: general-bi-cal with the remedies for a real arm's effects.

What the agent itself does (``payload-agent run`` / ``solve`` / ``calibrate``), through its own pure
analysis ``payload_agent.evaluation.analyse.analyse`` (systematic terms: ``evaluation.systematics``): the declared joint stiffness is compensated in the tool run,
the empty-flange baseline and the calibration reference run alike; the declared stiffness and
zero-offset uncertainties, the friction the two-direction average leaves (declared direction asymmetry ×
the friction change measured between the runs) and constant wrist torques sized from the data go into σ
and into the quality gate's pose comparison; the gate's tool-cable check does the rest.

The declared values are what a correctly configured agent knows about the simulated arm
(``benchmarks.hard.Declared``), as the robot YAML's ``robot.kinematics.stiffness_nm_per_rad``,
``stiffness_uncertainty_percent``, ``zero_offset_uncertainty_deg``, ``robot.friction_asymmetry_percent``,
``robot.friction_change_percent`` and ``robot.tool_cable_fitted`` would say; the realistic arm has none of these
effects and declares none.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmarks.gate import columns
from benchmarks.reference import calibration

COMP = "general-bi-cal-comp"
COMP3 = "three-step-bi-cal-comp"  # the agent's three-step solver on the same analysis (its σ as the agent reports it)


def declaration(declared):
    """``benchmarks.hard.Declared`` (or None: nothing) as the agent's ``JointSystematicsConfig``."""
    from payload_agent.configuration.config import JointSystematicsConfig
    from payload_agent.evaluation import systematics

    if declared is None:
        return systematics.RIGID
    return JointSystematicsConfig(declared.stiffness_nm_per_rad, declared.stiffness_rel_std,
                                  (declared.zero_offset_std_rad,) * 6, declared.friction_asymmetry_std,
                                  declared.friction_change_std, tool_cable_fitted=declared.tool_cable_fitted)


def scaled(sweeps: dict, scale: np.ndarray) -> dict:
    """Sweeps with their effort at the calibrated gains (what the agent loads after a calibration)."""
    return {k: dataclasses.replace(s, effort_nm=np.asarray(s.effort_nm) * scale) for k, s in sweeps.items()}


def calibrated_gains(cal, unfitted_std: float, shared: bool = True):
    """The ``analyse.Gains`` of a case's calibration (``benchmarks.reference.calibration``): its gains, their
    uncertainty (``unfitted_std`` for the joints it did not fit), its reference (the per-angle gain errors too) and
    zeros; ``shared``: the reference run was subtracted against the tool run's own empty run."""
    from payload_agent.evaluation.analyse import Gains

    return Gains(tuple(cal.gains_nm_per_unit), "calibrated on the benchmark's reference run", None,
                 tuple(float(v) for v in cal.gain_rel_std(unfitted_std)), cal.reference, cal.zeros,
                 shared_baseline=shared)


def comp_estimate(loaded: dict, empty: dict, ref: dict, declared, config, unfitted_std: float, kin_kw: dict,
                  solver: str = "general", mount_rad=None, cal=None):
    """(Estimate, gate columns) of general-bi-cal-comp (``solver`` "three-step": three-step-bi-cal-comp) on one
    case's recorded sweeps: the agent's own ``analyse`` (that solver only, as the other methods are compared
    separately) after the calibration; ``mount_rad``: the angles the loaded run started from (the tool cable's
    rest), as the agent records them. ``cal``: a calibration made elsewhere (``benchmarks.cross_calibration``: on
    another procedure against its own empty run, so no shared baseline; ``ref`` is then unused); None: this
    case's, on ``ref`` against ``empty``."""
    from payload_agent.evaluation.analyse import AnalysisOptions, analyse

    decl = declaration(declared)
    shared = cal is None  # the calibration's reference run and the tool run share this case's empty run, as
    # ``calibrate`` and ``run`` share the stored baseline
    if cal is None:
        cal = calibration(ref, empty, config, decl)  # what ``calibrate`` stores: gains, zeros, reference friction
    scale = np.asarray(cal.scale, float)
    options = AnalysisOptions(config.robot.kinematics, decl, kin_kw.get("length_std_m"), solver)
    gains = calibrated_gains(cal, unfitted_std, shared)
    result = analyse(scaled(loaded, scale), scaled(empty, scale), options, gains, solvers=(), mount_rad=mount_rad)
    return dataclasses.replace(result.primary, solver=COMP if solver == "general" else COMP3), columns(result.quality)


__all__ = ["COMP", "COMP3", "calibrated_gains", "comp_estimate", "declaration", "scaled"]
