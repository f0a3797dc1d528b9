"""The three-step solver's σ carries the DH lengths' uncertainty (``three_step.length_covariance``), as the general
solver's does: the simulated arm's true link lengths differ from the ones the agent is told, and the three-step
error they cause, with and without a drive-gain calibration that absorbed part of it, is what the term's
sensitivities predict."""

import dataclasses

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation import systematics
from payload_agent.evaluation.calibration import fit_from_sweeps
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general, three_step
from recorded_runs import record_runs

from benchmarks.reference import REFERENCE
from benchmarks.remedies import scaled
from conftest import ROOT

TOL = np.array([1e-4, 2e-5, 2e-5, 2e-5])  # kg, m: second order and the simulation's own error
TOOL = PayloadTruth.point(4.0, (50.0, -30.0, 110.0))
LENGTH_ERRORS_M = {(1, "a"): 2.0e-3, (3, "d"): -1.5e-3, (5, "d"): 1.0e-3}  # true − told, rows 0-based


@pytest.fixture(scope="module")
def runs():
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), source="sim-ec66.yaml")
    spec = ec66_spec()
    rows = list(spec.dh)
    for (i, which), err in LENGTH_ERRORS_M.items():
        rows[i] = dataclasses.replace(rows[i], **({"a_m": rows[i].a_m + err} if which == "a" else
                                                 {"d_m": rows[i].d_m + err}))
    true_arm = dataclasses.replace(spec, dh=tuple(rows))
    plan = make_plan(config)
    robot = SimRobot(true_arm, q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=3, noise_nm=0.0)
    empty, loaded, ref = record_runs(robot, plan, TOOL, PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    return config, empty, loaded, ref


def _error_and_prediction(config, loaded, empty, cal=None):
    kin = config.robot.kinematics
    scale = np.ones(6) if cal is None else np.asarray(cal.scale)
    deltas = systematics.prepare(scaled(loaded, scale), scaled(empty, scale), systematics.RIGID).deltas
    est = three_step.solve(deltas, kin)
    beta = np.array([est.mass_kg, *est.cog_m])
    D = three_step.length_sensitivities(deltas, kin, beta, None if cal is None else cal.reference,
                                        general.fit_model(deltas, kin))
    delta = np.array([LENGTH_ERRORS_M.get(p, 0.0) for p in general.length_parameters(kin)])
    truth = np.array([TOOL.mass_kg, *TOOL.cog_m])
    return beta - truth, delta @ D, D


def test_the_length_error_the_three_steps_show_is_the_one_the_term_predicts(runs):
    config, empty, loaded, ref = runs
    error, predicted, _ = _error_and_prediction(config, loaded, empty)
    assert abs(error[0]) > 0.003 and np.max(np.abs(error[1:])) > 0.5e-3  # grams and millimetres: a real effect
    assert np.all(np.abs(predicted - error) <= 0.03 * np.abs(error) + TOL), (predicted, error)
    # after a calibration on the same arm, part of it went into the gains of joints 2 and 3
    cal = fit_from_sweeps(ref, empty, config, REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0, joints=systematics.RIGID)
    error_cal, predicted_cal, _ = _error_and_prediction(config, loaded, empty, cal)
    assert np.all(np.abs(predicted_cal - error_cal) <= 0.03 * np.abs(error_cal) + TOL), (predicted_cal, error_cal)
    assert abs(error_cal[0] - error[0]) > 0.001  # the calibration moved the mass error: the absorption matters


def test_the_reported_sigma_carries_the_term(runs):
    config, empty, loaded, _ = runs
    kin = config.robot.kinematics
    deltas = systematics.prepare(loaded, empty, systematics.RIGID).deltas
    plain = three_step.solve(deltas, kin)
    with_lengths = three_step.solve(deltas, kin, length_std_m=0.3e-3)
    _, _, D = _error_and_prediction(config, loaded, empty)
    extra = (0.3e-3) ** 2 * (D.T @ D)
    assert with_lengths.mass_std_kg ** 2 == pytest.approx(plain.mass_std_kg ** 2 + extra[0, 0], rel=1e-6)
    for axis in range(3):
        assert with_lengths.cog_std_m[axis] ** 2 == pytest.approx(plain.cog_std_m[axis] ** 2 + extra[axis + 1, axis + 1],
                                                                  rel=1e-6)
