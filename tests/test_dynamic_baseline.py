"""The dynamic-model baseline (paper §3.4, eq. 29) on the simulated EC66.

The excitation run is simulated tick by tick (``benchmarks.excitation``); the solver sees only
time, joint angles and efforts, differentiates the angles itself and fits loaded − empty
with the payload's 10-parameter Newton–Euler regressor.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from payload_agent.fakes.arms import SPECS
from benchmarks.excitation import (MAX_ACCEL_RAD_S2, MAX_EXCURSION_RAD, MAX_SPEED_RAD_S,
                                            default_start, design_trajectory, record_excitation)
from payload_agent.fakes.physics import ArmPhysics, FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import SOLVERS, dynamic, regressor

MASS, COG_MM = 2.5, (40.0, -30.0, 90.0)


@pytest.fixture(scope="module")
def setup():
    spec = SPECS["ec66"]()
    kin = Kinematics(spec.dh)
    q0 = default_start(kin)
    traj = design_trajectory(kin, q0, candidates=8, periods=2, seed=1)
    return spec, kin, q0, traj


def _pair(spec, q0, traj, *, friction=None, noise=0.0, drift=0.0, gain=None, seed=3):
    robot = SimRobot(spec, q0_rad=q0, tick_s=0.008, friction=friction, noise_nm=noise, seed=seed)
    empty, _ = record_excitation(robot, traj, torque_scale=gain)
    robot.set_payload(PayloadTruth.point(MASS, COG_MM))
    robot.set_friction_scale(1.0 + drift)
    loaded, motion = record_excitation(robot, traj, torque_scale=gain)
    return loaded, empty, motion


def test_regressor_matches_mujoco_inverse_dynamics():
    """W·θ equals the difference of MuJoCo's inverse dynamics with and without the payload."""
    spec = SPECS["ec66"]()
    kin = Kinematics(spec.dh)
    truth = PayloadTruth(2.3, (0.04, -0.03, 0.09), (0.01, 0.02, 0.015))
    with_payload, without = ArmPhysics(spec, truth), ArmPhysics(spec, None)
    m, c = truth.mass_kg, np.array(truth.cog_m)
    # inertia about the flange origin: parallel-axis theorem
    I_o = np.diag(truth.inertia_kgm2) + m * (c @ c * np.eye(3) - np.outer(c, c))
    theta = np.array([m, *(m * c), I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2]])
    rng = np.random.default_rng(0)
    q, qd, qdd = rng.normal(size=(3, 20, 6))
    W = regressor.payload_regressor(kin, q, qd, qdd)
    for k in range(20):
        expected = with_payload.rigid_torque(q[k], qd[k], qdd[k]) - without.rigid_torque(q[k], qd[k], qdd[k])
        assert np.allclose(W[k] @ theta, expected, atol=1e-9)
    # static limit: the gravity regressor the PTP solvers use
    W0 = regressor.payload_regressor(kin, q, np.zeros_like(qd), np.zeros_like(qdd))
    assert np.allclose(W0[3, :, :4], kin.payload_regressor(q[3], range(6)), atol=1e-12)


def test_trajectory_bounded_and_at_rest_at_both_ends(setup):
    spec, kin, q0, traj = setup
    q, qd, qdd = traj.evaluate(np.linspace(0.0, traj.duration_s, 20001))
    assert np.max(np.abs(qd)) <= MAX_SPEED_RAD_S
    assert np.max(np.abs(qdd)) <= MAX_ACCEL_RAD_S2
    assert np.max(np.abs(q - q0)) <= MAX_EXCURSION_RAD
    assert np.allclose(q[[0, -1]], q0, atol=1e-12)
    assert np.allclose(qd[[0, -1]], 0.0, atol=1e-12) and np.allclose(qdd[[0, -1]], 0.0, atol=1e-9)
    assert np.allclose(q[:, :3], q0[:3])  # joints 1-3 held, as in the paper
    assert np.all(np.ptp(q[:, 3:], axis=0) > math.radians(20))  # joints 4-6 really move


def test_noise_free_recovers_mass_and_first_moments(setup):
    spec, kin, q0, traj = setup
    loaded, empty, motion = _pair(spec, q0, traj)
    assert motion == pytest.approx(traj.duration_s)
    est = dynamic.solve(loaded, empty, kin)
    assert est.mass_kg == pytest.approx(MASS, abs=1e-4)  # 0.1 g
    assert np.allclose(est.cog_mm, COG_MM, atol=0.01)
    assert est.mass_std_kg < 1e-3


def test_noisy_with_friction_drift_within_tolerance_and_honest_sigma(setup):
    """Noise 0.3 N·m, Coulomb + viscous + 5 % load-dependent friction, 10 % drift between runs."""
    spec, kin, q0, traj = setup
    friction = FrictionParams(np.array([4.0, 4.0, 3.0, 1.0, 1.0, 0.5]), np.array([8.0, 8.0, 5.0, 1.0, 1.0, 0.5]),
                              np.full(6, 0.05))
    loaded, empty, _ = _pair(spec, q0, traj, friction=friction, noise=0.3, drift=0.1)
    est = dynamic.solve(loaded, empty, kin)
    assert abs(est.mass_kg - MASS) < 0.02
    assert np.linalg.norm(np.subtract(est.cog_mm, COG_MM)) < 3.0
    assert abs(est.mass_kg - MASS) < 5 * est.mass_std_kg + 1e-3
    # without the friction-change columns the 10 % drift biases the fit much more
    naive = dynamic.solve(loaded, empty, kin, friction=False)
    assert abs(naive.mass_kg - MASS) > abs(est.mass_kg - MASS)


def test_not_registered_with_the_ptp_solvers():
    """It needs its own trajectory: evaluation.analyse.solve_all must not call it on PTP sweeps."""
    assert dynamic.NAME not in SOLVERS


def test_uneven_sampling_is_refused(setup):
    spec, kin, q0, traj = setup
    t = np.cumsum(np.r_[0.0, np.full(200, 0.008)])
    t[100:] += 0.004
    with pytest.raises(Exception, match="evenly spaced"):
        dynamic.derivatives(t, np.zeros((len(t), 6)))
