"""The drive-gain calibration measures the zeros of joints 2 and 3; the analysis and the plan use them.

A simulated EC66 whose encoder zeros are off (``PhysicsEffects.zero_offset_rad``, set here and not told to the
agent, whose robot YAML declares only ±0.2° of zero uncertainty) and whose drives report the torque 2 % high /
1.5 % low: the calibration with a 5 kg reference must find the zeros of joints 2 and 3 within their σ, a σ
well below the declared one, and the gains with them; a tool identified with that calibration is corrected
(its angles) and reports a smaller joint-zero term; and the plan predicts that term as the run reports it.
Runs are recorded in-process from the physics core and go through run folders, as in ``test_calibration``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation import systematics, zero_offsets
from payload_agent.evaluation.analyse import AnalysisOptions, Gains, analyse
from payload_agent.evaluation.calibration import fit_gains, save_calibration
from payload_agent.evaluation.pipeline import analyse_run
from payload_agent.evaluation.systematics import ALL, planned_covariance
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.effects import PhysicsEffects
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.recording.state import RobotState
from payload_agent.solvers import general

from conftest import tweak
from test_calibration import with_state, write_run

ZERO_DEG = np.array([0.05, 0.15, -0.10, 0.03, -0.04, 0.02])  # the truth: controller angle − link angle
PRIOR_DEG = 0.2  # what the robot YAML declares (zero_offset_uncertainty_deg)
TORQUE_SCALE = np.array([1.0, 1.02, 0.985, 1.0, 1.0, 1.0])  # what the drives report / true torque
REF_M, REF_C = 5.0, (0.060, 0.0, 0.080)
TOOL_M, TOOL_C = 2.0, (0.040, -0.025, 0.070)


@pytest.fixture(scope="module")
def sim(sim_ec66_data_module, tmp_path_factory):
    """Run folders: the reference (5 kg) and a tool (2 kg), each with its empty run, 5 %, the YAML's paper_bd."""
    data = tweak(sim_ec66_data_module, "robot.kinematics.zero_offset_uncertainty_deg", PRIOR_DEG)
    config = parse_config(tweak(tweak(data, "procedure.speed_percent", 5), "procedure.inertia", False),
                          source="sim-ec66.yaml")
    plan = make_plan(config)
    robot = SimRobot(SPECS["ec66"](), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008,
                     friction=FrictionParams(np.array([4.0, 4, 3, 1, 1, 0.5]), np.array([8.0, 8, 5, 1, 1, 0.5])),
                     noise_nm=0.3, seed=5, effects=PhysicsEffects(zero_offset_rad=tuple(np.radians(ZERO_DEG))))
    gains = np.asarray(config.effort.gains_nm_per_unit)
    tmp = tmp_path_factory.mktemp("zeros")
    runs = {}
    for name, m, c in (("ref", REF_M, REF_C), ("tool", TOOL_M, TOOL_C)):
        robot.set_payload(None)
        empty, _ = record_plan(robot, plan, torque_scale=TORQUE_SCALE)
        robot.set_payload(PayloadTruth.point(m, [1000 * v for v in c]))
        loaded, _ = record_plan(robot, plan, torque_scale=TORQUE_SCALE)
        runs[name] = (write_run(tmp / name, config, empty, loaded, gains), empty, loaded)
    config = with_state(config, tmp / "state")
    cal = fit_gains(config, runs["ref"][0], REF_M, REF_C)
    return config, runs, cal


@pytest.fixture(scope="module")
def sim_ec66_data_module():
    from pathlib import Path

    import yaml

    path = Path(__file__).resolve().parents[1] / "configs" / "sim-ec66.yaml"
    return yaml.safe_load(path.read_text(encoding="utf-8"))


def test_calibration_measures_the_zeros_of_joints_2_and_3(sim):
    _, _, cal = sim
    zeros = {z.joint: z for z in cal.zeros.joints}
    assert set(zeros) == {1, 2}  # joints 2 and 3: the wrist's zeros turn only the reference's short CoM offset
    for j, z in zeros.items():
        truth = math.radians(ZERO_DEG[j])
        assert z.measured and z.std_rad < math.radians(PRIOR_DEG) / 3, (j, z)  # the data tell it, not the prior
        assert abs(z.offset_rad - truth) < 3 * z.std_rad, (j, math.degrees(z.offset_rad), math.degrees(z.std_rad))
    two = zeros[1]
    assert abs(two.offset_rad) > 3 * two.std_rad  # joint 2's 0.15° is seen, not the prior's 0
    for j in (1, 2):  # the gains fitted with them are right within their σ (gains' and zeros' errors are coupled)
        assert abs(cal.scale[j] * TORQUE_SCALE[j] - 1) < 4 * cal.scale_std[j] + 1e-4, (j, cal.scale[j], cal.scale_std[j])
    assert 0 <= cal.zeros.max_gain_correlation <= 1 and cal.zeros.effort_coupling is not None


def test_the_analysis_corrects_the_angles_and_the_zero_term_shrinks(sim):
    config, runs, cal = sim
    save_calibration(RobotState.for_config(config), cal)
    result = analyse_run(config, runs["tool"][0], solver="general")
    p = result.primary
    assert [z["joint"] for z in result.extra["zero_offsets"]["joints"]] == [2, 3]
    assert any("joint zeros from the drive-gain calibration" in n and "corrected" in n for n in p.notes), p.notes
    assert abs(p.mass_kg - TOOL_M) < 3 * p.mass_std_kg, (p.mass_kg, p.mass_std_kg)
    for axis in range(3):
        assert abs(p.cog_m[axis] - TOOL_C[axis]) < 3 * p.cog_std_m[axis], (axis, p.cog_m, p.cog_std_m)
    # the same data and gains with the declared ±0.2° instead: the joint-zero term, and so σ, is larger
    g = np.asarray(cal.gains_nm_per_unit)
    _, empty, loaded = runs["tool"]
    scaled = [{k: dataclasses.replace(v, effort_nm=v.effort_nm * np.asarray(cal.scale)) for k, v in s.items()}
              for s in (loaded, empty)]
    options = AnalysisOptions.from_config(config, "general")
    declared = analyse(*scaled, options, Gains(tuple(g), "test", rel_std=cal.gain_rel_std(), reference=cal.reference))
    assert declared.primary.mass_std_kg > 1.5 * p.mass_std_kg, (declared.primary.mass_std_kg, p.mass_std_kg)


@pytest.mark.parametrize("prior_deg", [PRIOR_DEG, 0.02])
def test_the_plan_predicts_the_runs_zero_term(sim, prior_deg):
    """``systematics.planned_covariance`` (what ``plan --target-std`` adds) against the run's own joint-zero term
    on the same sweeps: the measured σ, their correlation and the gains coupled to them, alike (±30 %). With the
    real arms' ±0.02° as the prior the coupling decides the term's size, so its sign is checked too."""
    config, runs, _ = sim
    joints = dataclasses.replace(config.robot.joints, zero_offset_std_rad=(math.radians(prior_deg),) * 6)
    config = dataclasses.replace(config, robot=dataclasses.replace(config.robot, joints=joints))
    cal = fit_gains(config, runs["ref"][0], REF_M, REF_C)
    _, empty, loaded = runs["tool"]
    decl = zero_offsets.declaration(config.robot.joints, cal.zeros)
    lo, em = ({k: dataclasses.replace(v, effort_nm=v.effort_nm * np.asarray(cal.scale)) for k, v in
               zero_offsets.corrected(s, cal.zeros).items()} for s in (loaded, empty))
    kin = config.robot.kinematics
    prepared = systematics.prepare(lo, em, decl)
    model = general.fit_model(prepared.deltas, kin, cal.gain_rel_std())
    syst = systematics.evaluate(prepared, kin, decl, cal.gain_rel_std(), terms=[systematics.joint_terms], model=model)
    run_cov = next(t for t in syst.terms if t.name == "joint zeros").covariance(ALL)
    fit = model.fits()[ALL]

    def planned(d):
        return planned_covariance(list(model.sweeps), kin, d, fit.theta, fit.weights)

    plan_cov = planned(decl)
    for i in range(4):  # mass and the three first moments
        assert 0.7 < math.sqrt(plan_cov[i, i] / run_cov[i, i]) < 1.3, (i, plan_cov[i, i], run_cov[i, i])
    flipped = planned(dataclasses.replace(decl, zero_gain_coupling=tuple(tuple(-v for v in row)
                                                                           for row in decl.zero_gain_coupling)))
    declared = planned(config.robot.joints)
    assert plan_cov[0, 0] < 0.25 * declared[0, 0]  # the zero term shrinks: measured 0.14 against 0.62 g (±0.02°)
    if prior_deg < 0.1:  # a wrong sign would fit the gains' errors against the zeros' instead of with them
        assert flipped[0, 0] > 4 * plan_cov[0, 0], (flipped[0, 0], plan_cov[0, 0])


def test_a_stored_calibration_with_bad_zeros_is_refused_naming_the_file(sim):
    """A hand-edited gains.json: a zero on joint 9 is refused with the file named; a file from before (no zeros)
    still loads, without zeros, and the analysis then keeps the declared zero term."""
    import json

    from payload_agent.errors import DataError
    from payload_agent.evaluation.calibration import load_calibration

    config, _, cal = sim
    state = RobotState.for_config(config)
    save_calibration(state, cal)
    data = json.loads(state.gains_path.read_text(encoding="utf-8"))
    assert load_calibration(state, config) == cal
    data["zero_offsets"]["joints"][0]["joint"] = 9
    state.gains_path.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(DataError, match=r"gains\.json: cannot read the drive-gain calibration .*joints must be 1–6"):
        load_calibration(state, config)
    del data["zero_offsets"]
    state.gains_path.write_text(json.dumps(data), encoding="utf-8")
    assert load_calibration(state, config).zeros is None
    save_calibration(state, cal)  # as the other tests of this module expect it
