"""Systematic terms measured from the run itself (evaluation.systematics, issue 22): each recovers a term the
simulation set and the agent was not told, and shows nothing where the simulation set nothing."""

import dataclasses

import numpy as np
import pytest
import yaml

from payload_agent.analysis.combine import add_combined
from payload_agent.analysis.delta import subtract_all
from payload_agent.configuration.config import parse_config
from payload_agent.evaluation.systematics import offsets
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan

from conftest import ROOT

TRUTH = PayloadTruth.point(2.0, (40.0, -25.0, 70.0))
# constant torques on the still wrist joints 4–6 in poses b and d (N·m): what a weak tool cable or gear
# ripple under load puts there, and the model lacks
WRIST_NM = {"b": (0.08, -0.06, 0.07), "d": (-0.09, 0.06, -0.07)}


@pytest.fixture(scope="module")
def run():
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=3, noise_nm=0.3)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(TRUTH)
    loaded, _ = record_plan(robot, plan)
    return config.robot.kinematics, loaded, empty


def _with_wrist_torques(loaded):
    out = {}
    for key, s in loaded.items():
        e = np.array(s.effort_nm, float)
        e[:, 3:] += WRIST_NM[key.pose]
        out[key] = dataclasses.replace(s, effort_nm=e)
    return out


def _wrist_effect(deltas, kin):
    """What the wrist term takes from the data (``systematics.wrist.measure``): the wrist offsets b̂ by label
    ("b/j5") and the shrink s of their effect on θ, with the sensitivities the plain fit gives."""
    from payload_agent.evaluation.systematics import wrist
    from payload_agent.solvers import general

    model = general.fit_model(deltas, kin)
    sweeps, groups, res = list(model.sweeps), list(model.groups), model.fit()
    sens = offsets.offset_sensitivities(sweeps, groups, res.weights, res.normal_inverse, offsets.wrist_joint)
    labels = sorted(sens)
    w = wrist.measure(model, np.column_stack([sens[k] for k in labels]), labels)
    return dict(zip(labels, w.offsets_nm)), w.shrink


def test_the_wrist_torque_term_recovers_the_torques_the_simulation_added(run):
    kin, loaded, empty = run
    clean, _ = add_combined(subtract_all(loaded, empty))
    wrist, _ = add_combined(subtract_all(_with_wrist_torques(loaded), empty))
    true_rms = float(np.sqrt(np.mean(np.square(list(WRIST_NM.values())))))
    b, s = _wrist_effect(wrist, kin)
    assert {k.split("/")[0] for k in b} == set(WRIST_NM)  # one offset per (pose, still wrist joint)
    err = [v - WRIST_NM[k.split("/")[0]][int(k[-1]) - 4] for k, v in b.items()]
    assert float(np.sqrt(np.mean(np.square(err)))) < 0.35 * true_rms  # each torque recovered, to the noise
    assert s > 0.8  # well beyond the noise: nearly all of their effect goes into σ
    # none added: the offsets scatter as the noise says (χ² ≈ k), so nothing goes into σ (the method of
    # moments it replaced put tens of mN·m there whenever a badly determined offset came out large)
    b, s = _wrist_effect(clean, kin)
    assert s == 0.0 and float(np.sqrt(np.mean(np.square(list(b.values()))))) < 0.35 * true_rms


# a weak tool cable: one spring wound one way, so its torques share a sign (N·m; cf. benchmarks/hard.py:
# 0.01–0.02 N·m/rad over the 90–180° the wrist turns from where the tool was mounted)
CABLE_NM = {"b": (0.03, 0.025, 0.05), "d": (0.03, 0.0, 0.02)}


def _with(loaded, torques):
    out = {}
    for key, s in loaded.items():
        e = np.array(s.effort_nm, float)
        e[:, 3:] += torques.get(key.pose, 0.0)
        out[key] = dataclasses.replace(s, effort_nm=e)
    return out


def test_the_wrist_torque_term_is_the_size_of_what_a_weak_cable_does_to_the_mass(run):
    """The term is the torques' measured effect on θ: it covers the shift the cable causes (the isotropic size it
    replaced, b ~ N(0, σ_w²·I), put 0.9 g of this 6.1 g shift into σ), and is absent on the same run without it."""
    from payload_agent.evaluation import systematics
    from payload_agent.solvers import general

    kin, loaded, empty = run

    def mass_and_term(lo):
        prep = systematics.prepare(lo, empty, systematics.RIGID)
        model = general.fit_model(prep.deltas, kin)
        syst = systematics.evaluate(prep, kin, systematics.RIGID, terms=[systematics.wrist_terms], model=model)
        return model.fit().theta[0], float(np.sqrt(syst.covariance()[0, 0]))

    m_clean, term_clean = mass_and_term(loaded)
    m_cable, term_cable = mass_and_term(_with(loaded, CABLE_NM))
    shift = abs(m_cable - m_clean)  # the same noise in both: what the cable alone did
    assert shift > 0.004  # the effect is real: several grams on a 2 kg tool
    assert 0.7 * shift < term_cable < 2.0 * shift
    assert term_clean < 0.3 * term_cable


def test_ripple_on_still_joints_2_and_3_is_not_read_as_wrist_torques():
    """Load-dependent gear ripple on joints 1–3 only (none on the wrist): frozen at the angle joint 2 or 3 stands
    at, it scales the payload torque there by a few per mille; a fit with wrist offsets alone took up that misfit
    in the offsets (nearly confounded with m·c) and put it into σ as "wrist torques" (8–17 g in the benchmark's
    ripple ablation). With a nuisance gain column per (still joint, angle) beside the offsets the wrist term stays
    small, and the run's σ still covers the error: the torque-gain scatter term carries it."""
    from payload_agent.evaluation import systematics
    from payload_agent.evaluation.systematics import wrist
    from payload_agent.fakes.effects import PhysicsEffects, TorqueRipple
    from payload_agent.solvers import general

    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    plan, kin = make_plan(config), config.robot.kinematics
    truth = PayloadTruth.point(4.0, (-60.0, 50.0, 90.0))
    ripple = PhysicsEffects(ripple=TorqueRipple((0.3, 0.3, 0.3, 0.0, 0.0, 0.0), (0.01, 0.01, 0.01, 0.0, 0.0, 0.0)))
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=2, noise_nm=0.3,
                     effects=ripple)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(truth)
    loaded, _ = record_plan(robot, plan)
    prep = systematics.prepare(loaded, empty, systematics.RIGID)
    model = general.fit_model(prep.deltas, kin)
    sweeps, groups, res = list(model.sweeps), list(model.groups), model.fit()
    labels = sorted({offsets.wrist_joint(g, next(s for s in sweeps if s.key.name == g.sweep)) for g in groups} - {None})
    sens = offsets.offset_sensitivities(sweeps, groups, res.weights, res.normal_inverse, offsets.wrist_joint)
    A = np.column_stack([sens[lab] for lab in labels])

    alone = offsets.fit_offsets(prep.deltas, kin, offsets.wrist_joint, model=model)  # the offsets-only fit it replaced
    idx = [alone.labels.index(lab) for lab in labels]
    beta, D = A @ alone.offsets_nm[idx], A @ alone.offsets_cov[np.ix_(idx, idx)] @ A.T
    q = float(beta @ np.linalg.lstsq(D, beta, rcond=None)[0])
    before = abs(float(beta[0])) * np.sqrt(max(q - np.linalg.matrix_rank(D), 0.0) / q)
    w = wrist.measure(model, A, labels)
    after = w.shrink * abs(float((A @ w.offsets_nm)[0]))
    assert before > 0.008  # grams of "wrist torque" on an arm with none
    assert after < 0.2 * before

    syst = systematics.evaluate(prep, kin, systematics.RIGID, model=model)
    sigma = float(np.sqrt(res.cov[0, 0] + syst.covariance()[0, 0]))
    error = res.theta[0] - truth.mass_kg
    assert abs(error) > 3 * np.sqrt(res.cov[0, 0])  # the ripple's error is beyond the noise σ
    assert abs(error) < 2.0 * sigma
    assert any(t.name == "torque-gain scatter" for t in syst.terms)
