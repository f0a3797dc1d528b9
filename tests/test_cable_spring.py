"""The tool-cable term (``systematics.cable_spring``): a spring on the wrist relaxed where the tool was mounted.

Runs of the simulated EC66 (``fakes.offline.record_plan``) with and without a tool cable the physics core adds
(``fakes.effects.ToolCable``: relaxed where ``set_payload`` mounted the tool); the agent is told only where the
loaded run started, as it records it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation import systematics
from payload_agent.evaluation.systematics import cable_spring, offsets
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.effects import PhysicsEffects, ToolCable
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general
from payload_agent.solvers.fitted import ALL

from conftest import ROOT

TRUTH = PayloadTruth.point(2.0, (40.0, -25.0, 70.0))
CABLE_NM_PER_RAD = (0.06, 0.04, 0.05)  # a cable the test must find; the benchmark's weak one is 0.01–0.02


def _record(cable: tuple[float, float, float] | None, seed: int = 3):
    """(kin, loaded, empty, where the loaded run started) of the sim-ec66 procedure."""
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    plan = make_plan(config)
    effects = PhysicsEffects(tool_cable=ToolCable(cable)) if cable else PhysicsEffects()
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=seed,
                     noise_nm=0.3, effects=effects)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(TRUTH)
    mount = np.asarray(robot.snapshot().q, float)
    loaded, _ = record_plan(robot, plan)
    return config.robot.kinematics, loaded, empty, mount


@pytest.fixture(scope="module")
def runs():
    return {"clean": _record(None), "cable": _record(CABLE_NM_PER_RAD)}


def _spring(kin, loaded, empty, mount):
    prep = systematics.prepare(loaded, empty, systematics.RIGID, mount_rad=mount)
    model = general.fit_model(prep.deltas, kin)
    labels = sorted({offsets.wrist_joint(g, d) for g in model.groups for d in model.sweeps if d.key.name == g.sweep}
                    - {None})
    return prep, model, cable_spring.fit_spring(model, labels, mount)


def _mass_and_term(kin, loaded, empty, mount):
    prep, model, _ = _spring(kin, loaded, empty, mount)
    syst = systematics.evaluate(prep, kin, systematics.RIGID, terms=[systematics.wrist_terms], model=model)
    return model.fit().theta[0], syst


def test_the_spring_is_found_and_its_stiffness_recovered(runs):
    kin, loaded, empty, mount = runs["cable"]
    _, _, s = _spring(kin, loaded, empty, mount)
    assert s.present and s.weight == 1.0
    truth = np.asarray(CABLE_NM_PER_RAD)[[j - 3 for j in s.joints]]
    z = (s.stiffness_nm_per_rad - truth) / np.sqrt(np.diag(s.cov))
    assert np.all(np.abs(z) < 3.5), (s.stiffness_nm_per_rad, truth, np.sqrt(np.diag(s.cov)))


def test_the_term_covers_what_the_cable_does_to_the_mass_and_is_absent_without_it(runs):
    """The same seed with and without the cable: the shift of the plain mass is the cable's doing; the term's mass σ
    is of that size, and on the clean run the presence test stays below its 95 % quantile."""
    m_cable, syst_cable = _mass_and_term(*runs["cable"])
    m_clean, syst_clean = _mass_and_term(*runs["clean"])
    shift = abs(m_cable - m_clean)
    assert shift > 0.004  # grams on a 2 kg tool: the effect is real
    assert [t.name for t in syst_cable.terms] == ["tool cable"]
    term = float(np.sqrt(syst_cable.covariance()[0, 0]))
    assert 0.7 * shift < term < 3.0 * shift
    _, _, s = _spring(*runs["clean"])
    assert not s.present
    clean_term = float(np.sqrt(syst_clean.covariance()[0, 0]))
    assert clean_term < 0.3 * term


def test_without_the_mount_pose_the_free_wrist_offsets_stand_in(runs):
    kin, loaded, empty, _ = runs["cable"]
    prep = systematics.prepare(loaded, empty, systematics.RIGID)
    model = general.fit_model(prep.deltas, kin)
    syst = systematics.evaluate(prep, kin, systematics.RIGID, terms=[systematics.wrist_terms], model=model)
    assert [t.name for t in syst.terms] == ["wrist torques"]


def test_a_joint_that_never_leaves_the_mount_angle_has_no_spring_column(runs):
    kin, loaded, empty, mount = runs["cable"]
    prep, model, _ = _spring(kin, loaded, empty, mount)
    labels = sorted({offsets.wrist_joint(g, d) for g in model.groups for d in model.sweeps if d.key.name == g.sweep}
                    - {None})
    standing = {lab: np.mean([np.mean(d.q[:, int(lab[-1]) - 1]) for d in model.sweeps
                              if d.key.pose == lab.split("/")[0]]) for lab in labels}
    at_j6 = np.array(mount, float)
    at_j6[5] = standing[next(lab for lab in labels if lab.endswith("j6"))]  # j6 mounted where one pose stands
    M, joints = cable_spring.levers(list(model.sweeps), list(model.groups), labels, at_j6)
    j6 = [i for i, lab in enumerate(labels) if lab.endswith("j6")]
    assert 5 in joints  # the other pose still turns it
    assert sorted(abs(M[j6, joints.index(5)]))[0] < np.radians(0.05)
    everywhere = np.array(mount, float)
    everywhere[3:] = 1e3  # no joint stands near it: every joint has a lever
    assert cable_spring.levers(list(model.sweeps), list(model.groups), labels, everywhere)[1] == (3, 4, 5)


def test_the_statistic_is_the_chi_square_drop_to_the_nearest_non_negative_stiffness():
    """T = κ*ᵀC⁻¹κ* equals min over κ=0 minus min over κ ≥ 0 of (κ − κ̂)ᵀC⁻¹(κ − κ̂), by a brute-force grid."""
    C = np.array([[1.0, 0.6, -0.3], [0.6, 2.0, 0.4], [-0.3, 0.4, 0.5]])
    Ci = np.linalg.inv(C)
    for kappa in (np.array([0.8, -1.5, 0.3]), np.array([-1.0, -0.2, -0.4]), np.array([1.2, 0.9, 0.7])):
        g = np.linspace(0.0, 3.0, 61)
        grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        d = grid - kappa
        best = float(np.min(np.einsum("ni,ij,nj->n", d, Ci, d)))
        drop = float(kappa @ Ci @ kappa) - best
        assert cable_spring.statistic(kappa, C) == pytest.approx(drop, abs=0.02)


def test_the_presence_test_false_alarm_rate_is_its_alpha():
    """κ̂ ~ N(0, C) (no cable): T exceeds the drawn 95 % quantile in 5 % of 3000 independent draws (binomial 1σ
    0.4 %), for a correlated C; the quantile itself is a chi-bar-squared's, between χ²₁'s and χ²₃'s."""
    C = np.array([[1.0, 0.6, -0.3], [0.6, 2.0, 0.4], [-0.3, 0.4, 0.5]])
    crit, mean = cable_spring.null_distribution(C)
    rng = np.random.default_rng(7)
    L = np.linalg.cholesky(C)
    t = np.array([cable_spring.statistic(L @ z, C) for z in rng.standard_normal((3000, 3))])
    assert abs(np.mean(t > crit) - cable_spring.ALPHA) < 0.013
    assert 2.71 < crit < 7.81 and 0.5 < mean < 3.0


def test_a_torque_against_the_spring_sense_is_no_cable():
    """κ ≥ 0: torques that pull the wrist further from its rest are not a spring; the projection is 0, no term."""
    C = np.diag([1e-4, 1e-4])
    assert cable_spring.statistic(np.array([-0.05, -0.03]), C) == 0.0
    assert np.all(cable_spring.project(np.array([-0.05, -0.03]), C) == 0.0)


def test_the_term_reaches_every_fit_the_quality_gate_compares(runs):
    kin, loaded, empty, mount = runs["cable"]
    _, syst = _mass_and_term(kin, loaded, empty, mount)
    (term,) = syst.terms
    assert ALL in term.sens and len(term.sens) >= 3  # the combined fit and each pose's


def test_the_mount_angles_are_read_from_the_manifest_and_bad_ones_named(tmp_path):
    import json

    from payload_agent.errors import DataError
    from payload_agent.recording.rundata import mount_angles

    def write(loaded):
        (tmp_path / "manifest.json").write_text(json.dumps({"phases": {"empty": {}, "loaded": loaded}}))

    write({"sweeps": []})
    assert mount_angles(tmp_path) is None  # an older run: the free wrist offsets then
    write({"sweeps": [], "start_joint_angles_rad": [0.0, -1.0, 1.5, 3.1, 1.6, 0.0]})
    assert np.allclose(mount_angles(tmp_path), [0.0, -1.0, 1.5, 3.1, 1.6, 0.0])
    write({"sweeps": [], "start_joint_angles_rad": [0.0, 1.0, "x"]})
    with pytest.raises(DataError, match=r"phases\.loaded\.start_joint_angles_rad must be 6 joint angles"):
        mount_angles(tmp_path)


def test_the_null_distribution_matches_a_published_chi_bar_squared_tail():
    """GAUSS's ``chiBarSquare`` documentation (docs/sources.md) works an example: three parameters bounded below by
    0, its covariance argument the inverse of the V it lists, statistic 3.860509, tail probability 0.10885. The
    same tail of T, drawn as the presence test draws it (20000 draws: binomial 1σ 0.0022)."""
    V = np.array([[0.0005255598, -0.0006871606, -0.0003191342], [-0.0006871606, 0.0037466205, 0.0012285813],
                  [-0.0003191342, 0.0012285813, 0.0009081412]])
    C = np.linalg.inv(V)
    R = np.linalg.cholesky(V).T  # RᵀR = C⁻¹ = V
    rng = np.random.default_rng(11)
    t = np.array([cable_spring.statistic(np.linalg.solve(R, u), C) for u in rng.standard_normal((20000, 3))])
    assert abs(np.mean(t > 3.860509) - 0.10885) < 0.007


def test_the_face_enumeration_agrees_with_non_negative_least_squares():
    """``statistics`` (all draws at once, by the faces of κ ≥ 0) and ``project`` (scipy's NNLS, one at a time) give
    the same T on 500 random estimates of a correlated C."""
    C = np.array([[1.0, 0.6, -0.3], [0.6, 2.0, 0.4], [-0.3, 0.4, 0.5]])
    Ci = np.linalg.inv(C)
    R = np.linalg.cholesky(Ci).T
    kappas = np.random.default_rng(5).standard_normal((500, 3)) * 1.5
    fast = cable_spring.statistics(R, kappas @ R.T)
    slow = [float(k @ Ci @ k) for k in (cable_spring.project(kk, C) for kk in kappas)]
    assert np.allclose(fast, slow, atol=1e-9)
    assert np.any(fast == 0.0)  # estimates in the polar cone (1 % here): T = 0 there, through the same code


def test_gear_ripple_the_calibration_absorbed_is_not_read_as_a_cable():
    """Gear ripple under load on joints 2 and 3 (1 % of the gear torque, frozen where a joint stands) in the
    drive-gain calibration's reference run and in the tool run, no cable. Until session 24 the calibration's scale of
    each joint took a share of its still clusters' gain errors, so the tool data's moving rows carried the opposite
    error; the wrist rows' level then disagreed with θ̂ and the spring read it as stiffness (on this seed the presence
    test fired, T = 12, with the nuisance gain columns measured only relative to their joint's rows). Now the
    calibration fits each standing angle's own gain error apart from the joint's gain (``gain_scales.own_scales``), so
    no share is absorbed: the estimate is within noise of no cable either way the columns are measured."""
    from payload_agent.evaluation.calibration import fit_from_sweeps
    from payload_agent.fakes.effects import TorqueRipple

    from benchmarks.reference import REFERENCE
    from benchmarks.remedies import scaled

    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    plan = make_plan(config)
    ripple = TorqueRipple((0.0, 0.3, 0.3, 0.0, 0.0, 0.0), (0.0, 0.01, 0.01, 0.0, 0.0, 0.0))
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=3, noise_nm=0.3,
                     effects=PhysicsEffects(ripple=ripple))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    ref, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(4.0, (40.0, -25.0, 70.0)))
    mount = np.asarray(robot.snapshot().q, float)
    loaded, _ = record_plan(robot, plan)
    cal = fit_from_sweeps(ref, empty, config, REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0)
    scale = np.asarray(cal.scale, float)
    # as the analysis reads a calibrated run: the calibration's per-angle gain errors off the still rows standing at
    # its angles (this run stands at all of them)
    prep = systematics.prepare(scaled(loaded, scale), scaled(empty, scale), systematics.RIGID, mount_rad=mount,
                               gain_reference=cal.reference)
    assert prep.still_scales
    model = general.fit_model(prep.deltas, config.robot.kinematics, list(cal.gain_rel_std(0.0)))
    labels = sorted({offsets.wrist_joint(g, d) for g in model.groups for d in model.sweeps if d.key.name == g.sweep}
                    - {None})
    # without the moving arm joints' nuisance offsets (``moving_arm_joint``, session 18), which take up part of the
    # moving rows' gain error as well, so that this seed still shows the effect
    relative = cable_spring.fit_spring(model, labels, mount, arm_offsets=None)
    assert not relative.present  # before session 24: found (the calibration's absorbed ripple read as a cable)
    for arm_offsets in (None, cable_spring.moving_arm_joint):
        absolute = cable_spring.fit_spring(model, labels, mount, gain_reference=cal.reference, arm_offsets=arm_offsets)
        assert not absolute.present
        z = absolute.estimate / np.sqrt(np.diag(absolute.cov))
        assert np.all(np.abs(z) < 2.0), z


# -- a cable the robot YAML declares (robot.tool_cable_fitted): κ's posterior on κ ≥ 0 -------------------------

def test_a_declared_cable_is_taken_out_at_every_strength_where_the_test_weight_leaves_it_in():
    """κ̂ ~ N(κ, C) for cables of 0, 0.5 and 1 σ per joint (the benchmark's weak cable at fast sweeps): declared, the
    result loses A·M·κ̂ (``cable_spring.term``) and what is left, a·(κ − κ̂), lies within 1.96 of the term's σ in
    93–97 % of 300 draws at every strength, centred (its mean within 3 s.e. of 0); the presence test's weight
    (``shares``) leaves a·κ in the result and misses it in more than 10 % of draws at 0.5 and 1 σ."""
    C = np.array([[1.0, 0.6, -0.3], [0.6, 2.0, 0.4], [-0.3, 0.4, 0.5]])
    a, L = np.array([1.0, 0.7, 1.2]), np.linalg.cholesky(C)
    sens = {ALL: np.vstack([a, np.zeros((3, 3))])}  # one quantity's response to κ (levers: the identity)
    crit, null_mean = cable_spring.null_distribution(C)
    draws = np.random.default_rng(5).standard_normal((300, 3))  # the same κ̂ − κ at every strength
    for strength in (0.0, 0.5, 1.0):
        kappa = strength * np.sqrt(np.diag(C))
        left, declared, tested = [], [], []
        for e in draws:
            estimate = kappa + L @ e
            star = cable_spring.project(estimate, C)
            s = cable_spring.CableSpring((3, 4, 5), np.eye(3), star, C, cable_spring.statistic(estimate, C), crit,
                                         null_mean, estimate, declared=True)
            t = cable_spring.term(s, sens)
            left.append(a @ kappa - t.shift[ALL][0])
            declared.append(abs(left[-1]) <= 1.96 * np.sqrt(t.covariance()[0, 0]))
            tested.append(abs(a @ kappa) <= 1.96 * np.sqrt(dataclasses.replace(s, declared=False).weight)
                          * abs(a @ star))
        assert 0.93 <= np.mean(declared) <= 0.97, (strength, np.mean(declared))
        assert abs(np.mean(left)) < 3 * np.std(left) / np.sqrt(len(left)), (strength, np.mean(left))
        if strength > 0:
            assert np.mean(tested) <= 0.9, (strength, np.mean(tested))


def test_a_declared_cable_is_the_spring_fit_where_found_and_prices_the_clean_arm(runs):
    """``robot.tool_cable_fitted`` (``JointSystematicsConfig.tool_cable_fitted``): on the found cable κ̂ lies far inside
    κ ≥ 0, its posterior is N(κ̂, C), so θ̂ loses the measured effect A·M·κ̂ and σ holds its noise D = A·M·C·MᵀAᵀ (the
    fit with the spring fitted, Frisch–Waugh); on the clean run declaring costs that noise too, which the presence
    test spares in most clean runs (why it is not the default)."""
    from dataclasses import replace

    declared = replace(systematics.RIGID, tool_cable_fitted=True)

    def term(run, declaration):
        kin, loaded, empty, mount = run
        prep = systematics.prepare(loaded, empty, declaration, mount_rad=mount)
        syst = systematics.evaluate(prep, kin, declaration, terms=[systematics.wrist_terms],
                                    model=general.fit_model(prep.deltas, kin))
        return syst

    found, tested = term(runs["cable"], declared), term(runs["cable"], systematics.RIGID)
    assert "declared fitted" in found.terms[0].note and "found" in tested.terms[0].note
    cols = tested.terms[0].sens[ALL]  # [A·M·κ*, A·M·chol(C)]
    D = cols[:, 1:] @ cols[:, 1:].T
    assert 0.8 < found.covariance()[0, 0] / D[0, 0] < 1.25
    assert np.allclose(found.shift(), cols[:, 0], rtol=0.05, atol=0.05 * float(np.max(np.abs(cols[:, 0]))))
    clean, chance = term(runs["clean"], declared), term(runs["clean"], systematics.RIGID)  # seed 3: a chance term
    cols = chance.terms[0].sens[ALL]
    assert clean.covariance()[0, 0] == pytest.approx(cols[0, 1:] @ cols[0, 1:], rel=1e-9)


def _declared_result(run):
    """(reported estimate, plain estimate, the quality gate's per-pose results) of the general solver on ``run``
    with ``robot.tool_cable_fitted`` declared, through the recipe the analysis uses (``Systematics.apply``)."""
    from dataclasses import replace

    from payload_agent.evaluation import quality

    kin, loaded, empty, mount = run
    declared = replace(systematics.RIGID, tool_cable_fitted=True)
    prep = systematics.prepare(loaded, empty, declared, mount_rad=mount)
    model = general.fit_model(prep.deltas, kin)
    syst = systematics.evaluate(prep, kin, declared, terms=[systematics.wrist_terms], model=model)
    plain = general.estimate(model)
    reported = syst.apply(plain)
    gate = quality.evaluate(prep.deltas, kin, reported, systematics=syst, model=model)
    return reported, plain, gate["per_pose"]


def test_a_declared_cable_is_taken_out_of_the_result_not_carried_in_sigma(runs):
    """A spring that resists pushes the plain fit one way (+19 g of mass and 9 mm of CoM on this 2 kg tool): declared,
    the reported mass and CoM are the same seed's without the cable to within a third of that push (3.3 g, 1.7 mm),
    and within 2 σ (mass) and 3 σ (CoM) of the truth, where σ no longer holds the push. Until session 21 the reported θ̂ was the plain fit's
    and σ carried the push as if it were noise (fails there: the reported result is the plain one)."""
    reported, plain, poses = _declared_result(runs["cable"])
    _, clean, _ = _declared_result(runs["clean"])
    push = plain.mass_kg - clean.mass_kg
    assert abs(push) > 0.004
    assert abs(reported.mass_kg - clean.mass_kg) < 0.35 * abs(push), (reported.mass_kg, plain.mass_kg, clean.mass_kg)
    push_c = np.subtract(plain.cog_mm, clean.cog_mm)
    moved = np.subtract(reported.cog_mm, clean.cog_mm)
    assert np.linalg.norm(moved) < 0.35 * np.linalg.norm(push_c), (moved, push_c)
    assert abs(reported.mass_kg - TRUTH.mass_kg) < 2.0 * reported.mass_std_kg
    cog_err = np.subtract(reported.cog_mm, 1000 * np.asarray(TRUTH.cog_m))  # this seed: z 1.7 / 0.1 / 2.0
    assert np.all(np.abs(cog_err) < 3000 * np.asarray(reported.cog_std_m))
    assert reported.mass_std_kg < 0.5 * abs(push)  # σ holds the correction's uncertainty, not the push
    assert any("removed from the result" in n and "flat prior" in n for n in reported.notes)
    # each pose's own fit loses its own share of the push (the gate compares poses on corrected fits)
    for pose in poses.values():
        assert abs(pose["mass_kg"] - clean.mass_kg) < 0.5 * abs(push)


# -- the arm joints' friction residual beside the spring (``cable_spring.moving_arm_joint``) -----------------------

def test_the_arm_joints_friction_residual_does_not_pull_the_stiffness_low():
    """A Coulomb direction asymmetry on joints 1–3 and a friction level 20 % higher in the loaded run than in the
    empty one leave a constant on every moving arm joint's rows that the two-direction average does not cancel
    (larger than the benchmark's ±15 % and ±10 %, so that it shows at this procedure's speed as they do at 1 %
    sweeps: docs/benchmarks.md, session 17). Fitted beside one nuisance offset per moving arm joint, κ̂ agrees with
    the cable (χ² against the truth in C's metric below its 99 % quantile) and with κ̂ on the same arm without the
    asymmetry; without those offsets it lies far below."""
    from scipy.stats import chi2

    from benchmarks.cases import COULOMB_NM, VISCOUS_NM_S_RAD
    from payload_agent.fakes.physics import FrictionParams

    cable = (0.02, 0.015, 0.02)  # the benchmark's weak cable's range is 0.005–0.02
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    plan = make_plan(config)

    def spring(asymmetry: float, scale: float, **fit_options):
        effects = PhysicsEffects(tool_cable=ToolCable(cable), coulomb_asymmetry=(asymmetry, -asymmetry, asymmetry,
                                                                                 0.0, 0.0, 0.0))
        friction = FrictionParams(np.array(COULOMB_NM), np.array(VISCOUS_NM_S_RAD), np.zeros(6))
        robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=4,
                         noise_nm=0.3, effects=effects, friction=friction)
        empty, _ = record_plan(robot, plan)
        robot.set_payload(TRUTH)
        mount = np.asarray(robot.snapshot().q, float)
        robot.set_friction_scale(scale)
        loaded, _ = record_plan(robot, plan)
        prep = systematics.prepare(loaded, empty, systematics.RIGID, mount_rad=mount)
        model = general.fit_model(prep.deltas, config.robot.kinematics)
        labels = sorted({offsets.wrist_joint(g, d) for g in model.groups for d in model.sweeps
                         if d.key.name == g.sweep} - {None})
        return cable_spring.fit_spring(model, labels, mount, **fit_options)  # as the run fits it, unless told

    def chi_square(s):
        d = s.estimate - np.asarray(cable)[[j - 3 for j in s.joints]]
        return float(d @ np.linalg.solve(s.cov, d))

    limit = chi2.ppf(0.99, 3)
    fixed = spring(0.3, 1.2)
    symmetric = spring(0.0, 1.0)
    assert fixed.joints == (3, 4, 5) and chi_square(fixed) < limit, chi_square(fixed)
    assert np.all(np.abs(fixed.estimate - symmetric.estimate) < 0.5 * np.sqrt(np.diag(fixed.cov)))
    assert chi_square(spring(0.3, 1.2, arm_offsets=None)) > 3 * limit  # the fit before: κ̂ pulled low


# -- a declared cable's correction and the drive gains (session 22) ------------------------------------------------

def test_a_declared_cables_sigma_holds_what_a_wrist_gain_error_does_to_the_corrected_result(runs):
    """A gain error of a wrist drive scales that joint's payload torque, which moves the plain fit and the spring's κ̂
    together, so the corrected result θ̂_plain − A·M·κ̂ moves by their difference. The part of the reported
    covariance a 2 % gain uncertainty of joint 4 adds equals the square of what a 2 % error of that gain (every
    recorded effort of joint 4 scaled by 1.02) does to the reported mass and CoM z: within 15 % (measured 1.06 /
    1.07). Until session 22 σ took the plain fit's and κ̂'s parts as independent, a² + (A·M·k)²: 0.53 / 0.56 of it
    on this run, where the two move the result the same way (fails there)."""
    from dataclasses import replace

    from benchmarks.remedies import scaled

    kin, loaded, empty, mount = runs["cable"]
    declared = replace(systematics.RIGID, tool_cable_fitted=True)

    def reported(gain_std, scale):
        prep = systematics.prepare(scaled(loaded, scale), scaled(empty, scale), declared, mount_rad=mount)
        model = general.fit_model(prep.deltas, kin, gain_std)
        syst = systematics.evaluate(prep, kin, declared, gain_std, terms=[systematics.wrist_terms], model=model)
        assert [t.name for t in syst.terms] == ["tool cable"] and syst.terms[0].shift
        est = syst.apply(general.estimate(model))
        return np.array([est.mass_kg, *(est.mass_kg * np.asarray(est.cog_m))]), np.asarray(est.covariance)[:4, :4]

    one = np.eye(6)[3]
    theta, cov_none = reported(np.zeros(6), np.ones(6))
    _, cov_gain = reported(0.02 * one, np.ones(6))
    moved, _ = reported(np.zeros(6), 1.0 + 0.02 * one)
    ratio = np.diag(cov_gain - cov_none)[[0, 3]] / (moved - theta)[[0, 3]] ** 2
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
