"""The plan predicts the torque-gain term a run carries where it stands at the calibration's angles.

A noisy offline EC66 (``fakes.offline``, the accuracy benchmark's procedure at 20 %, the hard scenario's load-dependent
mesh ripple on joints 1–3): an empty run, the calibration's 3 kg reference run, a 4 kg tool run, all standing at the
same angles. The calibration stores each standing angle's own gain error ε̂ ± σ_ε; the tool run's rows standing
there are divided by 1 + ε̂ (``calibration_clusters``) and its torque-gain term gives those clusters the prior σ_ε²
(``gain_scatter.corrected_prior``), whose expected effect on θ is S·diag(σ_ε²)·Sᵀ. ``plan --target-std`` must
predict that term for the same procedure (``planned_scatter``, ``design.covariance_terms``'s "scatter"), or the
plan's σ misses what the run reports.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import cases
from benchmarks.reference import REFERENCE
from benchmarks.remedies import scaled
from payload_agent.evaluation import calibration_clusters, design, systematics
from payload_agent.evaluation.calibration import fit_from_sweeps
from payload_agent.evaluation.systematics import gain_scatter
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.effects import PhysicsEffects, TorqueRipple
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.solvers import general
from payload_agent.solvers.fitted import ALL
from payload_agent.solvers.wls import cog_with_covariance

NOISE_NM = 0.3
TOOL = (4.0, (40.0, -30.0, 120.0))  # kg, mm: another torque than the reference's


@pytest.fixture(scope="module")
def calibrated_run():
    """(the procedure's plan, its config, the calibration, the tool run's prepared deltas with its correction)."""
    proc = cases.Procedure("20", 20.0, cases.SPEED_ROW_TRAVEL, cases.SPEED_ROW_ACCEL, *cases.SWEEP_DEG)
    plan, _, config = cases.plans(proc)
    ripple = TorqueRipple(0.0, (0.01,) * 3 + (0.0,) * 3, 100.0, once_per_rev_fraction=0.0)
    friction = FrictionParams(np.array(cases.COULOMB_NM), np.array(cases.VISCOUS_NM_S_RAD), np.zeros(6))
    robot = SimRobot(SPECS["ec66"](), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=cases.TICK_S,
                     friction=friction, noise_nm=NOISE_NM, seed=12, effects=PhysicsEffects(ripple=ripple))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    ref, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(TOOL[0], TOOL[1]))
    tool, _ = record_plan(robot, plan)
    cal = fit_from_sweeps(ref, empty, config, REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0)
    scale = np.asarray(cal.scale, float)
    prepared = systematics.prepare(scaled(tool, scale), scaled(empty, scale), systematics.RIGID,
                                   gain_reference=cal.reference)
    return plan, config, cal, prepared


def test_the_plans_torque_gain_term_is_the_runs_for_the_clusters_the_calibration_corrected(calibrated_run):
    """The run's expected term for its corrected clusters, S·diag(σ_ε²)·Sᵀ with its own fit's weights, against the
    plan's for the same procedure with the noise the run had (each joint's residual σ, sweeping and standing apart).
    They agree within 5 % in the mass (2.1 g here) and 10 % in the CoM's largest axis; main's plan has no such
    term."""
    plan, config, cal, prepared = calibrated_run
    kin = config.robot.kinematics
    gain_std = list(cal.gain_rel_std(0.03))
    model = general.fit_model(prepared.deltas, kin, gain_std)
    fits = model.fits()
    groups = model.groups_of(ALL)
    term = gain_scatter.term(prepared.deltas, kin, gain_std, {w: (model.groups_of(w), f) for w, f in fits.items()},
                             ALL, model, cal.reference)
    assert prepared.still_scales and term is not None and term.prior_var is not None
    corrected = {name for g, name in zip(groups, gain_scatter.clusters(list(model.sweeps), groups))
                 if (g.sweep, g.joint) in calibration_clusters.matches(list(model.sweeps), cal.reference)}
    # joint 2 stands at −90° in pose b's joint-3 sweeps, joint 3 at 0°; joint 4, which never turns, at 180° in both
    # poses, its reference torque of one sign in each (``still_joint_scales``; its ε̂ ≈ 0 here, no ripple on the wrist)
    assert corrected == {"j2@-90.00°", "j3@0.00°", "j4@180.00°"}
    prior = np.where([label in corrected for label in term.labels], term.prior_var, 0.0)
    run = (term.sens[ALL] * prior) @ term.sens[ALL].T

    # the plan's noise model: the residual σ the run's fit found, per joint, sweeping and standing apart
    moving = {d.key.name: d.moving for d in model.sweeps}
    sweeping, standing = np.full(6, NOISE_NM), np.full(6, NOISE_NM)
    for j in range(6):
        for out, still in ((sweeping, False), (standing, True)):
            found = [fits[ALL].sigma_nm[g.label] for g in groups if g.joint == j and (moving[g.sweep] != j) == still]
            out[j] = np.median(found) if found else NOISE_NM
    noise = design.NoiseModel(tuple(sweeping), cases.TICK_S, gain_rel_std=tuple(gain_std),
                              gain_reference=cal.reference, effort_rest_std_nm=tuple(standing))
    theta = design.nominal_theta(TOOL[0], TOOL[1])
    planned = design.covariance_terms(config, plan, noise, theta)[0]["scatter"]
    assert 1000.0 * np.sqrt(run[0, 0]) > 0.2  # g: the term is there (σ_ε of 0.2 % on tens of N·m standing)
    assert np.sqrt(planned[0, 0]) == pytest.approx(np.sqrt(run[0, 0]), rel=0.05)  # the mass
    # the centre of mass, largest axis (what the plan reports; z here, 0.08 mm): the smaller axes differ more
    cog = [np.sqrt(np.max(np.diag(cog_with_covariance(theta, c)[1]))) for c in (planned, run)]
    assert cog[0] == pytest.approx(cog[1], rel=0.1)
