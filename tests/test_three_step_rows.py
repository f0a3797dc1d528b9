"""A constant torque on the three-step's rows that is not friction, in the three-step's σ (issue 22 item 2).

The simulated arm's tool run has its friction level 10 % below the baseline's (measured by the agent) and a
constant torque more on joint 2 while joint 2 sweeps, in both directions and both poses: 0.13 N·m is what the hard
arm's gear ripple left there at 1 % sweeps through the pooled calibration (docs/benchmarks.md, session 23: −0.135 /
−0.122 N·m in poses b / d on case 6). Since session 25 the offsets are fitted beside the still clusters' gains and
measure it to ±0.046 N·m, where the declared asymmetry (8.7 %) × the change can leave ±0.033 N·m: 0.13 N·m is then
within what friction can leave (χ² 6.9 of 10.83) and 0.26 N·m is not. Beyond it the residual-friction term does not
read the torque as friction; the three-step solver reads it straight into its mass."""

import dataclasses

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation import systematics
from payload_agent.evaluation.systematics import three_step_response, three_step_rows
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import three_step

from conftest import ROOT

TRUTH = PayloadTruth.point(3.0, (40.0, -25.0, 90.0))
OTHER_NM = 0.13  # a torque on joint 2's moving rows the payload model lacks
BEYOND_NM = 0.26  # one beyond what the declared asymmetry × the change can leave there
DROP = 0.10


def _with_torque(sweeps, nm):
    """The loaded run with ``nm`` more on joint 2 wherever joint 2 sweeps."""
    out = {}
    for key, s in sweeps.items():
        effort = np.array(s.effort_nm, float)
        if key.joint == 2:
            effort[:, 1] += nm
        out[key] = dataclasses.replace(s, effort_nm=effort)
    return out


@pytest.fixture(scope="module")
def run():
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=5, noise_nm=0.3,
                     friction=FrictionParams((4.0, 4.0, 3.0, 1.0, 1.0, 0.5), (8.0, 8.0, 5.0, 1.0, 1.0, 0.5),
                                             np.full(6, 0.05)))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(TRUTH)
    robot.set_friction_scale(1.0 - DROP)
    loaded, _ = record_plan(robot, plan)
    joints = dataclasses.replace(config.robot.joints, friction_asymmetry_std=0.087, friction_change_std=0.1)
    return config.robot.kinematics, empty, loaded, joints


def test_a_torque_not_read_as_friction_is_in_the_three_step_sigma_as_measured(run):
    kin, empty, loaded, joints = run
    clean = systematics.prepare(loaded, empty, joints)
    prepared = systematics.prepare(_with_torque(loaded, BEYOND_NM), empty, joints)
    syst = systematics.evaluate(prepared, kin, joints)
    fric = next(t for t in syst.terms if t.name == "residual friction")
    assert "j2" in fric.note and "not used" in fric.note  # not friction: the declared prior decides there
    rows = next(t for t in syst.terms if t.name == three_step_rows.NAME)
    assert not any(t.name == three_step_rows.NAME for t in systematics.evaluate(clean, kin, joints).terms)

    # what the torque does to the three-step's result (the same noise, with and without it)
    shift = three_step_response.theta(prepared.deltas, kin) - three_step_response.theta(clean.deltas, kin)
    assert abs(shift[0]) > 0.040  # tens of grams on a 3 kg tool

    # the three-step's σ holds it as measured: the reported mass covers the shift, and the term's mean column (the
    # measured offset's effect) predicts it
    plain = three_step.solve(prepared.deltas, kin)
    reported = syst.apply(plain, systematics.THREE_STEP)
    assert abs(shift[0]) < 2.0 * reported.mass_std_kg
    assert rows.sens[systematics.THREE_STEP][0, 0] == pytest.approx(shift[0], rel=0.2)
    # the general fits take none of it (their σ is as before)
    for which, S in rows.sens.items():
        if which != systematics.THREE_STEP:
            assert not S.any(), which


def _still_scaled(deltas, factor):
    """The deltas with joints 2 and 3's still rows (where the other one sweeps) scaled by ``factor``: a gain error
    of their standing angles, as the frozen gear-mesh ripple makes and the calibration's per-angle correction
    (``calibration_clusters``, ≤ 1 %) takes off."""
    out = {}
    for key, d in deltas.items():
        dtau = np.array(d.dtau, float)
        for j in (1, 2):
            if j != d.moving:
                dtau[:, j] *= factor
        out[key] = dataclasses.replace(d, dtau=dtau)
    return out


def test_the_offsets_do_not_read_a_still_angles_gain_as_a_torque_on_the_moving_rows(run):
    """Session 24's per-angle correction changed the still rows by ≤ 1 % and moved the residual-friction term's
    three-step part 9.3 → 69 g (hard 1 %, case 6) and took `three step rows` (45 g, case 0) away: the offsets were
    fitted with θ̂ pinned by the still rows, so a still angle's gain error read as a constant on the moving rows
    (here 1 % moved b̂ of joint 2 by 0.21 N·m, 12 σ). Fitted beside one gain column per still cluster, b̂ and the term
    stay where they are under that scale, and still read a real constant on the moving rows one for one."""
    from payload_agent.evaluation.systematics import residual_friction
    from payload_agent.solvers import general

    kin, empty, loaded, joints = run

    def analysed(torque_nm, factor):
        prepared = systematics.prepare(_with_torque(loaded, torque_nm), empty, joints)
        prepared = dataclasses.replace(prepared, deltas=_still_scaled(prepared.deltas, factor))
        measured = residual_friction.measure(general.fit_model(prepared.deltas, kin))
        terms = {t.name: t for t in systematics.evaluate(prepared, kin, joints).terms}
        return measured, terms

    base, base_terms = analysed(0.0, 1.0)
    scaled, scaled_terms = analysed(0.0, 1.01)
    sd = np.sqrt(np.diag(base.cov))
    assert np.all(np.abs(scaled.offsets_nm - base.offsets_nm) < 0.2 * sd), (base.offsets_nm, scaled.offsets_nm, sd)
    assert (three_step_rows.NAME in scaled_terms) == (three_step_rows.NAME in base_terms)
    for key in (systematics.ALL, systematics.THREE_STEP):
        before = base_terms["residual friction"].covariance(key)[0, 0]
        after = scaled_terms["residual friction"].covariance(key)[0, 0]
        assert after == pytest.approx(before, rel=0.1), key

    # a torque on the moving rows is still measured as one
    torqued, _ = analysed(OTHER_NM, 1.0)
    assert torqued.offsets_nm[0] - base.offsets_nm[0] == pytest.approx(OTHER_NM, abs=0.1 * OTHER_NM)
    assert abs(torqued.offsets_nm[1] - base.offsets_nm[1]) < 0.1 * OTHER_NM
