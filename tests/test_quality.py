"""Quality gates: a clean identification passes; a wrong drive gain, a missing tool or disagreeing poses fail."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from payload_agent.delta import DeltaSweep
from payload_agent.errors import DataError, QualityGateError
from payload_agent.quality import evaluate, require_passed
from payload_agent.results import RunResult
from payload_agent.solvers import general

from test_general_solver import planned_sweeps, synthetic


@pytest.fixture(scope="module")
def base():
    config, sweeps = planned_sweeps(n=150)
    kin = config.robot.kinematics
    return kin, synthetic(sweeps, kin)


def noisy(clean, seed, noise=0.3, joint_scale=None, drop_payload=False, shift_pose=None):
    rng = np.random.default_rng(seed)
    out = {}
    for k, d in clean.items():
        dtau = np.zeros_like(d.dtau) if drop_payload else d.dtau.copy()
        if joint_scale is not None:
            dtau = dtau * joint_scale
        if shift_pose == k.pose:  # the tool slipped: pose d sees 5 % more torque on every joint
            dtau = dtau * 1.05
        out[k] = DeltaSweep(k, d.q, dtau + rng.normal(0.0, noise, dtau.shape), d.speed_rad_s)
    return out


def gate(kin, deltas):
    est = general.solve(deltas, kin)
    q = evaluate(deltas, kin, est)
    return q, RunResult("sim-ec66", "runs/x", est, quality=q)


def failed(q):
    return {c["check"] for c in q["checks"] if not c["passed"]}


def test_clean_runs_pass_across_seeds(base):
    kin, clean = base
    for seed in range(5):
        q, result = gate(kin, noisy(clean, seed))
        assert q["passed"], (seed, q["reasons"])
        require_passed(result)  # does not raise
        names = {c["check"] for c in q["checks"]}
        assert {"mass pose b vs pose d", "cog x pose b vs pose d", "condition number", "mass significance",
                "samples per sweep (fewest)", "residual / noise (worst sweep and joint)",
                "drive gain consistency joint 2", "drive gain consistency joint 3"} <= names
        for c in q["checks"]:
            assert {"check", "value", "limit", "passed"} <= set(c)


def test_gross_gain_error_fails(base):
    kin, clean = base
    scale = np.array([1, 1, 1.15, 1, 1, 1.0])  # joint 3's drive reports 15 % too much
    q, result = gate(kin, noisy(clean, 1, joint_scale=scale))
    assert not q["passed"]
    assert "drive gain consistency joint 3" in failed(q)
    with pytest.raises(QualityGateError, match=r"drive gain consistency joint 3: .*limit.*calibrate"):
        require_passed(result)


def test_realistic_gain_error_passes(base):
    kin, clean = base
    q, _ = gate(kin, noisy(clean, 2, joint_scale=np.array([1, 1.03, 0.97, 1.02, 0.98, 1.0])))
    assert not {c for c in failed(q) if c.startswith("drive gain")}, q["reasons"]


def test_tool_missing_fails(base):
    kin, clean = base
    for seed in range(3):
        deltas = noisy(clean, seed, drop_payload=True)
        try:
            q, result = gate(kin, deltas)
        except DataError as exc:  # a non-positive mass is refused by the solver itself
            assert "not positive" in str(exc)
            continue
        assert "mass significance" in failed(q)
        with pytest.raises(QualityGateError, match="mass significance"):
            require_passed(result)


def test_pose_disagreement_fails(base):
    kin, clean = base
    q, result = gate(kin, noisy(clean, 4, shift_pose="d"))
    assert "mass pose b vs pose d" in failed(q)
    with pytest.raises(QualityGateError, match=r"mass pose b vs pose d: \d"):
        require_passed(result)


def test_too_few_samples_fails(base):
    kin, clean = base
    short = {k: dataclasses.replace(d, q=d.q[:40], dtau=d.dtau[:40]) for k, d in noisy(clean, 5).items()}
    q, _ = gate(kin, short)
    assert "samples per sweep (fewest)" in failed(q)


def test_missing_quality_refused():
    with pytest.raises(QualityGateError):
        require_passed({"mass_kg": 1.0})
