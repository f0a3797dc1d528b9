"""The pose-agreement check of a three-pose procedure (j2_triple): its limits hold the two-pose procedure's
family-wise false-refusal rate over three pairs, and it still refuses a tool that moved between poses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.configuration.config import load_config
from payload_agent.errors import QualityGateError
from payload_agent.evaluation import quality
from payload_agent.evaluation.quality import evaluate, pose_agreement_limits, require_passed
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general
from payload_agent.solvers.results import RunResult

from test_general_solver import CONFIG, synthetic

CAL_GAIN_REL_STD = [0.03, 0.005, 0.005, 0.03, 0.03, 0.03]
LENGTH_STD_M = 0.0005


@pytest.fixture(scope="module")
def triple():
    """Clean Δτ along the planned sweeps of j2_triple (0–20°), three poses p, q, r."""
    config = load_config(CONFIG)
    config = dataclasses.replace(config, procedure=dataclasses.replace(
        config.procedure, name="j2_triple", sweep_from_deg=0.0, sweep_to_deg=20.0, inertia=None))
    sweeps, prev = [], None
    for move in make_plan(config).moves:
        target = np.asarray(move.target_rad)
        if move.sweep is not None:
            s = np.linspace(0.02, 0.98, 150)[:, None]
            sweeps.append((move.sweep, prev + s * (target - prev)))
        prev = target
    kin = config.robot.kinematics
    return kin, synthetic(sweeps, kin)


def noisy(clean, seed, *, scale_pose=None, offset_pose=None, noise=0.3):
    """Sensor noise on every sweep; ``scale_pose``: that pose's payload torque × 1.05 on every joint (the tool
    slipped); ``offset_pose``: a constant 1.5 N·m on joint 2 in that pose's sweeps (friction not cancelled)."""
    rng = np.random.default_rng(seed)
    out = {}
    for k, d in clean.items():
        dtau = d.dtau * (1.05 if k.pose == scale_pose else 1.0)
        if k.pose == offset_pose:
            dtau = dtau.copy()
            dtau[:, 1] += 1.5
        out[k] = DeltaSweep(k, d.q, dtau + rng.normal(0.0, noise, dtau.shape), d.speed_rad_s)
    return out


def gate(kin, deltas, **kw):
    est = general.solve(deltas, kin, **kw)
    q = evaluate(deltas, kin, est, **kw)
    return q, RunResult("sim-ec66", "runs/x", est, quality=q)


def pose_checks(q):
    return [c for c in q["checks"] if " pose " in c["check"] and " vs " in c["check"]]


def test_limits_keep_the_two_pose_family_rate():
    """One pair: the paper's two-pose limits, unchanged. More pairs: Šidák, so the family-wise rate of all
    pairs is the one-pair rate; the limits grow with the number of pairs."""
    assert pose_agreement_limits(1) == (quality.POSE_AGREEMENT_Z, quality.POSE_AGREEMENT_COG_Z)
    one = quality.pose_agreement_family_rate(1)
    assert one == pytest.approx(1 - (1 - math.erfc(3.0 / math.sqrt(2))) * (1 - math.erfc(3.5 / math.sqrt(2))) ** 3)
    m3, c3 = pose_agreement_limits(3)
    assert 3.0 < m3 < pose_agreement_limits(6)[0] and 3.5 < c3 < pose_agreement_limits(6)[1]
    for n in (2, 3, 6, 10):
        assert quality.pose_agreement_family_rate(n) == pytest.approx(one, rel=1e-9)
        zm, zc = pose_agreement_limits(n)
        # each test's two-sided rate is the Šidák share of the one-pair test's
        assert 1 - (1 - math.erfc(zm / math.sqrt(2))) ** n == pytest.approx(math.erfc(3.0 / math.sqrt(2)), rel=1e-9)
        assert 1 - (1 - math.erfc(zc / math.sqrt(2))) ** n == pytest.approx(math.erfc(3.5 / math.sqrt(2)), rel=1e-9)


def test_triple_clean_runs_pass_with_the_three_pair_limits(triple):
    kin, clean = triple
    m3, c3 = pose_agreement_limits(3)
    for seed in range(3):
        q, result = gate(kin, noisy(clean, seed), gain_rel_std=CAL_GAIN_REL_STD, length_std_m=LENGTH_STD_M)
        checks = pose_checks(q)
        assert {c["check"] for c in checks} >= {"mass pose p vs pose q", "mass pose p vs pose r",
                                                "mass pose q vs pose r", "cog z pose q vs pose r"}
        assert len(checks) == 12
        for c in checks:
            assert c["limit"] == pytest.approx(m3 if c["check"].startswith("mass") else c3)
        assert q["passed"], (seed, q["reasons"])
        require_passed(result)


@pytest.mark.parametrize("fault", ["tool moved before pose r", "friction not cancelled in pose q"])
def test_triple_still_refuses_what_the_check_is_for(triple, fault):
    kin, clean = triple
    if fault.startswith("tool"):
        deltas, bad = noisy(clean, 4, scale_pose="r"), "r"
    else:
        deltas, bad = noisy(clean, 4, offset_pose="q"), "q"
    q, result = gate(kin, deltas, gain_rel_std=CAL_GAIN_REL_STD, length_std_m=LENGTH_STD_M)
    refused = [c for c in pose_checks(q) if not c["passed"]]
    assert refused, [(c["check"], round(c["value"], 2)) for c in pose_checks(q)]
    assert all(f"pose {bad}" in c["check"] for c in refused)  # only the pairs with the bad pose
    assert not q["passed"]
    with pytest.raises(QualityGateError, match=r"pose [pqr] vs pose [pqr]: \d"):
        require_passed(result)
