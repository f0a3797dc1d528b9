"""The three-step solver's σ under gear ripple (``systematics.three_step_scatter``).

Offline recordings of the simulated EC66 (the sim-ec66 procedure, ``fakes.offline.record_plan``) with the gears'
load-dependent mesh ripple on joints 2 and 3 (``fakes.effects.TorqueRipple``: 1 % of the gear torque, frozen where a
joint stands), the drive-gain calibration on the benchmark's reference payload on the same arm, and a tool the test
sets and the agent is not told. The same robot seed with the ripple off gives the same sensor noise, so the
difference is what the ripple does. Low sensor noise, so that the ripple's error is the one σ must cover.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation import systematics
from payload_agent.evaluation.systematics import three_step_response, three_step_scatter
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.effects import PhysicsEffects, TorqueRipple
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general

from benchmarks.reference import REFERENCE, calibration
from benchmarks.remedies import comp_estimate, scaled
from conftest import ROOT

TRUTH = PayloadTruth.point(4.0, (40.0, -25.0, 70.0))
RIPPLE = TorqueRipple((0.0, 0.3, 0.3, 0.0, 0.0, 0.0), (0.0, 0.01, 0.01, 0.0, 0.0, 0.0))
NOISE_NM = 0.05
SEEDS = (1, 3)  # arms whose ripple phases move the three-step's mass by 12 and 15 g


@pytest.fixture(scope="module")
def config():
    return parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")


def _record(config, seed: int, ripple: bool) -> dict:
    """The empty, the reference and the tool run of one arm, in that order, as ``calibrate`` then ``run`` would."""
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=seed,
                     noise_nm=NOISE_NM, effects=PhysicsEffects(ripple=RIPPLE if ripple else TorqueRipple()))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    ref, _ = record_plan(robot, plan)
    robot.set_payload(TRUTH)
    mount = np.asarray(robot.snapshot().q, float)
    loaded, _ = record_plan(robot, plan)
    return {"empty": empty, "ref": ref, "loaded": loaded, "mount": mount}


@pytest.fixture(scope="module")
def runs(config):
    return {(seed, ripple): _record(config, seed, ripple) for seed in SEEDS for ripple in (True, False)}


def _prepared(config, run: dict):
    """(deltas at the calibrated gains, the fitted model, the calibration, the three-step's θ on the deltas)."""
    cal = calibration(run["ref"], run["empty"], config)
    scale = np.asarray(cal.scale, float)
    prep = systematics.prepare(scaled(run["loaded"], scale), scaled(run["empty"], scale), systematics.RIGID)
    kin = config.robot.kinematics
    model = general.fit_model(prep.deltas, kin, list(cal.gain_rel_std(0.0)))
    return prep.deltas, model, cal, three_step_response.theta(prep.deltas, kin)


def _three_step(config, run: dict):
    """The agent's own analysis after the calibration, the three-step solver primary: (error, σ) of m, x, y, z."""
    est, _ = comp_estimate(run["loaded"], run["empty"], run["ref"], None, config, 0.0, {"length_std_m": None},
                           "three-step", run["mount"])
    error = np.array([est.mass_kg - TRUTH.mass_kg, *(np.asarray(est.cog_m) - np.asarray(TRUTH.cog_m))])
    return error, np.array([est.mass_std_kg, *est.cog_std_m]), est


@pytest.mark.parametrize("seed", SEEDS)
def test_the_ripple_no_longer_reaches_the_three_steps_through_the_calibration(config, runs, seed):
    """The still joints' ripple reached the three steps only through the calibrated gains of joints 2 and 3, which
    took a share of each standing angle's gain error: 12 and 15 g on these arms before session 24, which this term
    carried in σ. The calibration now fits each standing angle of a joint that also turns its own scale
    (``gain_scales.own_scales``): the ripple moves the three-step's mass by a fraction of a gram (0.12 / 0.05 g, the
    same noise with the ripple off) and no share is left for the term."""
    kin = config.robot.kinematics
    deltas, model, cal, theta3 = _prepared(config, runs[(seed, True)])
    *_, clean3 = _prepared(config, runs[(seed, False)])
    shift = theta3 - clean3
    assert abs(shift[0]) < 0.002  # kg
    assert three_step_scatter.effect(deltas, kin, model, cal.reference, theta3) is None


@pytest.mark.parametrize("seed", SEEDS)
def test_the_three_step_sigma_covers_its_ripple_error(config, runs, seed):
    """Through the agent's own analysis: with the ripple the three-step's error is the one without it within a gram
    (before session 24 it was many times the σ without ripple), and the σ it reports covers it. (That σ is 5–6 × the
    σ without ripple while the error is not: the moving joints' mesh ripple counted as noise; docs/benchmarks.md,
    "Session 24", not done.)"""
    error, sigma, est = _three_step(config, runs[(seed, True)])
    clean_error, _, _ = _three_step(config, runs[(seed, False)])
    assert abs(error[0] - clean_error[0]) < 0.001
    assert np.all(np.abs(error) <= 1.2 * sigma), error / sigma


def test_no_term_on_an_arm_without_ripple_or_without_a_calibration(config, runs):
    """The term is measured, nothing declared: no scatter beyond noise, no term; and without a drive-gain calibration
    the three steps read no still joint's gain at all."""
    kin = config.robot.kinematics
    for seed in SEEDS:
        deltas, model, cal, theta3 = _prepared(config, runs[(seed, False)])
        assert three_step_scatter.effect(deltas, kin, model, cal.reference, theta3) is None
        deltas, model, _, theta3 = _prepared(config, runs[(seed, True)])
        assert three_step_scatter.effect(deltas, kin, model, None, theta3) is None
