"""The batch regressors compute the same numbers as the per-sample ones (and as an independent
reference: the textbook np.cross formula on ``Kinematics.pose``, and the Newton–Euler regressor
at rest), on random joint angles for two real arm geometries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from payload_agent.configuration.config import load_config
from payload_agent.model.kinematics import GRAVITY_M_S2
from payload_agent.solvers import regressor as R

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
N = 64
TOL = 1e-12


@pytest.fixture(params=["sim-ec66.yaml", "sim-ur5e.yaml"])
def kin(request):
    return load_config(CONFIGS / request.param).robot.kinematics


def _angles(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-np.pi, np.pi, (N, 6))


def _reference_static(kin, q, joints, g=GRAVITY_M_S2):
    """Static gravity rows written the plain way, one sample, from the single-pose kinematics."""
    pose = kin.pose(q)
    p, Rf = pose.flange[:3, 3], pose.flange[:3, :3]
    gvec = np.array([0.0, 0.0, g])
    return np.array([np.concatenate(([pose.axis(j) @ np.cross(p - pose.origin(j), gvec)],
                                     Rf.T @ np.cross(gvec, pose.axis(j)))) for j in joints])


def _reference_centripetal(kin, q, joints, moving, speed):
    pose = kin.pose(q)
    p, Rf = pose.flange[:3, 3], pose.flange[:3, :3]
    zk, ok = pose.axis(moving), pose.origin(moving)
    A = np.outer(zk, zk) - np.eye(3)
    f_m = A @ (p - ok)
    rows = []
    for j in joints:
        z, a = pose.axis(j), p - pose.origin(j)
        rows.append(speed ** 2 * np.concatenate(([z @ np.cross(a, f_m)], Rf.T @ (A @ np.cross(z, a) + np.cross(f_m, z)))))
    return np.array(rows)


@pytest.mark.parametrize("joints", [range(6), (1, 2, 3, 4, 5), (4, 2)])
def test_static_batch_equals_per_sample(kin, joints):
    q = _angles(1)
    Y = kin.payload_regressors(q, joints)
    assert Y.shape == (N, len(tuple(joints)), 4)
    single = np.stack([kin.payload_regressor(qi, joints) for qi in q])
    reference = np.stack([_reference_static(kin, qi, joints) for qi in q])
    assert np.abs(Y - single).max() <= TOL
    assert np.abs(Y - reference).max() <= TOL
    assert np.abs(Y).max() > 1.0  # not trivially zero: gravity torques of a real arm
    # an independent path: the Newton–Euler regressor at rest, first four columns
    W = R.payload_regressor(kin, q, np.zeros_like(q), np.zeros_like(q))[:, list(joints), :4]
    assert np.abs(Y - W).max() <= TOL


def test_other_gravity_scales_linearly(kin):
    q = _angles(2)
    assert np.abs(kin.payload_regressors(q, range(6), g=2.0 * GRAVITY_M_S2)
                  - 2.0 * kin.payload_regressors(q, range(6))).max() <= TOL


@pytest.mark.parametrize("moving", [0, 2, 4])
def test_centripetal_batch_equals_per_sample(kin, moving):
    q, joints, speed = _angles(3), (1, 2, 3, 4, 5), 0.4
    C = R.centripetal_regressors(kin, q, joints, moving, speed)
    reference = np.stack([_reference_centripetal(kin, qi, joints, moving, speed) for qi in q])
    assert np.abs(C).max() > 1e-3
    assert np.abs(C - reference).max() <= TOL
    assert np.abs(C - np.stack([R.centripetal_regressor(kin, qi, joints, moving, speed) for qi in q])).max() <= TOL
    full = R.regressors(kin, q, joints, moving, speed)
    assert np.abs(full - np.stack([R.regressor(kin, qi, joints, moving, speed) for qi in q])).max() <= TOL
    assert np.abs(full - (kin.payload_regressors(q, joints) + reference)).max() <= TOL


@pytest.mark.parametrize("moving", [0, 1, 4])
def test_newton_euler_first_moments_equal_gravity_plus_centripetal(kin, moving):
    """``payload_regressor(..., inertia=False)`` (what every PTP fit builds its rows from) is the gravity and
    centripetal rows written independently above, for one joint turning at constant speed (the joints before
    it stand still: the recursion skips them), and the first four columns of the full regressor when every
    joint moves and accelerates."""
    q, speed = _angles(5), -0.6
    qd = np.zeros_like(q)
    qd[:, moving] = speed
    W = R.payload_regressor(kin, q, qd, np.zeros_like(q), inertia=False)
    assert W.shape == (N, 6, 4)
    expected = kin.payload_regressors(q, range(6)) + np.stack(
        [_reference_centripetal(kin, qi, range(6), moving, speed) for qi in q])
    assert np.abs(W - expected).max() <= TOL
    rng = np.random.default_rng(6)
    qd, qdd = rng.normal(0.0, 1.0, (N, 6)), rng.normal(0.0, 2.0, (N, 6))
    full = R.payload_regressor(kin, q, qd, qdd)
    assert full.shape == (N, 6, 10) and np.abs(full[:, :, 4:]).max() > 1e-3
    assert np.abs(R.payload_regressor(kin, q, qd, qdd, inertia=False) - full[:, :, :4]).max() <= TOL


def test_shapes_and_bad_input(kin):
    assert kin.payload_regressors(np.zeros((0, 6)), range(6)).shape == (0, 6, 4)
    assert kin.payload_regressor(np.zeros(6), range(6)).shape == (6, 4)
    assert np.array_equal(R.centripetal_regressors(kin, _angles(4), range(6), 1, 0.0), np.zeros((N, 6, 4)))
    with pytest.raises(ValueError, match="6 joint angles"):
        kin.payload_regressor(np.zeros(5), range(6))
    with pytest.raises(ValueError, match="6 joint angles"):
        kin.payload_regressors(np.zeros((3, 5)), range(6))
