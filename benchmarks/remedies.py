"""The benchmark method general-bi-cal-comp: general-bi-cal with the remedies for a real arm's effects.

What the agent would do once the lead hooks the new modules into the pipeline:

1. compensate the declared joint stiffness (``solvers.compliance.compensate``) in the tool run, the
   empty-flange baseline and the calibration reference run alike;
2. widen σ by the declared stiffness and zero-offset uncertainties (``compliance.systematic_covariance``);
3. widen σ by the friction the two-direction average leaves, even in speed (direction asymmetry × a
   friction change between the runs: temperature, drift), sized from the friction level the baseline
   shows (``offsets.friction_offset_covariance``). PA_BENCH_OFFSETS=1 fits those offsets instead
   (``offsets.solve``): less bias from asymmetry, more from slow gear ripple (docs/benchmarks.md);
4. widen σ by constant wrist torques the data show (a weak tool cable, load-dependent gear ripple on a
   wrist joint standing still), sized from the data (``offsets.wrist_offset_covariance``);
5. add the tool-cable check (``evaluation.cable_check``) to the quality gate.

The declared values are what a correctly configured agent knows about the simulated arm
(``benchmarks.hard.Declared``).
"""

from __future__ import annotations

import os

import numpy as np

from benchmarks.cases import COMP, _calibrate, _gate, _scaled, theta_reference

FRICTION_OFFSETS = os.environ.get('PA_BENCH_OFFSETS') == '1'


def comp_estimate(loaded: dict, empty: dict, ref: dict, declared, config, unfitted_std: float, kin_kw: dict):
    """(Estimate, gate columns) of general-bi-cal-comp on one case's recorded sweeps."""
    from payload_agent.analysis.combine import add_combined
    from payload_agent.analysis.delta import subtract_all
    from payload_agent.evaluation import cable_check
    from payload_agent.solvers import compliance, general, offsets

    kin = config.robot.kinematics
    decl = compliance.JointSystematics() if declared is None else compliance.JointSystematics(
        declared.stiffness_nm_per_rad, declared.stiffness_rel_std, declared.zero_offset_std_rad)
    c = decl.compliance()
    empty_c = compliance.compensate(empty, c)
    scale, gain_rel_std, fitted = _calibrate(compliance.compensate(ref, c), empty_c, config, unfitted_std)
    kw = dict(kin_kw, gain_rel_std=list(gain_rel_std), gain_reference=(theta_reference(), fitted))

    def deltas_of(lo, em):
        combined, _ = add_combined(subtract_all(lo, em))
        return _scaled(combined, scale)

    def estimate_of(lo, em):
        if FRICTION_OFFSETS:
            return offsets.solve(deltas_of(lo, em), kin, name=COMP, **kw)
        return general.solve(deltas_of(lo, em), kin, name=COMP, **kw)

    est = compliance.solve_with_systematics(loaded, empty, decl, estimate_of)
    gate_deltas = deltas_of(compliance.compensate(loaded, c), empty_c)
    wrist_cov, wrist_nm = offsets.wrist_offset_covariance(gate_deltas, kin, gain_rel_std)
    if wrist_nm > 0:
        est = compliance.with_covariance(est, np.asarray(est.covariance) + wrist_cov,
                                         note=f"constant wrist torques of {1000 * wrist_nm:.0f} mN·m rms in σ")
    rel = 0.0 if declared is None else declared.friction_even_rel_std
    if rel > 0:
        extra = offsets.friction_offset_covariance(gate_deltas, kin, offsets.odd_friction_nm(empty_c), rel,
                                                   gain_rel_std)
        est = compliance.with_covariance(est, np.asarray(est.covariance) + extra,
                                         note=f"friction asymmetry × change (±{100 * rel:.2g} % of the baseline's "
                                              "friction) in σ")
    gate = _gate(gate_deltas, kin, est, **kw)
    cable = cable_check.check(gate_deltas, kin, gain_rel_std=gain_rel_std)
    gate["gate_values"][cable["check"]] = cable["value"]
    gate["cable"] = {k: cable.get(k) for k in ("chi2", "chi2_limit", "mass_shift_g", "cog_shift_mm", "passed")}
    if not cable["passed"]:
        gate["gate_passed"] = False
        gate["gate_failed"] = [*gate["gate_failed"], cable["check"]]
    return est, gate


__all__ = ["comp_estimate"]
