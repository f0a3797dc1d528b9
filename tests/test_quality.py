"""Quality gates: a clean identification passes; a wrong drive gain, a missing tool or disagreeing poses fail."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError, QualityGateError
from payload_agent.evaluation.quality import evaluate, require_passed
from payload_agent.solvers.results import RunResult
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


# --- the pose-agreement check with the primary solve's uncertainty terms -------------------------------

CAL_GAIN_REL_STD = [0.03, 0.005, 0.005, 0.03, 0.03, 0.03]  # a calibration: joints 2-3 fitted, others nominal
LENGTH_STD_M = 0.0005  # robot.kinematics.length_uncertainty_mm default


def _arm_with_length_errors(kin, seed, size_m=LENGTH_STD_M):
    """The nominal kinematics with every non-zero DH length off by ±size_m (random signs)."""
    params = general.length_parameters(kin)
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], len(params))
    for (row, which), s in zip(params, signs):
        kin = general.perturbed(kin, row, which, s * size_m)
    return kin


def gate_with_terms(kin, deltas, **kw):
    est = general.solve(deltas, kin, **kw)
    q = evaluate(deltas, kin, est, **kw)
    return q, RunResult("sim-ec66", "runs/x", est, quality=q)


def test_pose_agreement_includes_dh_length_uncertainty():
    """An arm whose DH lengths are off by 0.5 mm, measured with little noise: the two poses disagree by
    more than their noise allows (a false alarm of a noise-only comparison) but not by more than the declared
    length uncertainty allows. The length error is common to both poses, so the difference's σ (mass) is
    well below the quadrature sum of the per-pose σ."""
    config, sweeps = planned_sweeps(n=150)
    kin = config.robot.kinematics
    noise_only_failed = 0
    for seed in range(2):
        deltas = noisy(synthetic(sweeps, _arm_with_length_errors(kin, seed)), seed, noise=0.03)
        q0, _ = gate(kin, deltas)
        noise_only_failed += any(c.startswith("cog") and "pose" in c for c in failed(q0))
        q, result = gate_with_terms(kin, deltas, length_std_m=LENGTH_STD_M)
        assert q["passed"], (seed, q["reasons"])
        require_passed(result)
        mass = next(c for c in q["checks"] if c["check"] == "mass pose b vs pose d")
        pb, pd = q["per_pose"]["b"], q["per_pose"]["d"]
        assert mass["sigma_kg"] < 0.5 * np.hypot(pb["mass_std_kg"], pd["mass_std_kg"])
        assert "DH-length" in q["pose_agreement_sigma"]
    assert noise_only_failed  # what the terms are for


@pytest.mark.parametrize("case", ["gain 10 % joint 3", "tool missing", "pose d +5 %", "too few samples"])
def test_gross_faults_still_fail_with_uncertainty_terms(base, case):
    """With a calibration's gain uncertainty and 0.5 mm length uncertainty in the checks, what must fail still does."""
    kin, clean = base
    kw = {"gain_rel_std": CAL_GAIN_REL_STD, "length_std_m": LENGTH_STD_M}
    if case == "gain 10 % joint 3":
        q, result = gate_with_terms(kin, noisy(clean, 1, joint_scale=np.array([1, 1, 1.10, 1, 1, 1.0])), **kw)
        assert "drive gain consistency joint 3" in failed(q)
    elif case == "tool missing":
        deltas = noisy(clean, 0, drop_payload=True)
        try:
            q, result = gate_with_terms(kin, deltas, **kw)
        except DataError as exc:
            assert "not positive" in str(exc)
            return
        assert "mass significance" in failed(q)
    elif case == "pose d +5 %":
        q, result = gate_with_terms(kin, noisy(clean, 4, shift_pose="d"), **kw)
        assert "mass pose b vs pose d" in failed(q)
    else:
        short = {k: dataclasses.replace(d, q=d.q[:40], dtau=d.dtau[:40]) for k, d in noisy(clean, 5).items()}
        q, result = gate_with_terms(kin, short, **kw)
        assert "samples per sweep (fewest)" in failed(q)
    assert not q["passed"]
    with pytest.raises(QualityGateError):
        require_passed(result)


def test_clean_runs_pass_with_uncertainty_terms(base):
    kin, clean = base
    for seed in range(3):
        q, _ = gate_with_terms(kin, noisy(clean, seed), gain_rel_std=CAL_GAIN_REL_STD, length_std_m=LENGTH_STD_M)
        assert q["passed"], (seed, q["reasons"])


def test_primary_without_uncertainty_fails_and_three_step_primary_is_gated(base):
    """The gate judges whichever solver is primary: no uncertainty fails; a three-step primary that
    disagrees with the general estimate fails, one that agrees passes."""
    from payload_agent.solvers import three_step
    from payload_agent.solvers.results import Estimate

    kin, clean = base
    deltas = noisy(clean, 3)
    gen = general.solve(deltas, kin)
    bare = Estimate("my-solver", gen.mass_kg, gen.cog_m)
    q = evaluate(deltas, kin, bare, others=[gen])
    assert not q["passed"] and "uncertainty reported (my-solver)" in failed(q)

    ts = three_step.solve(deltas, kin)
    q = evaluate(deltas, kin, ts, others=[gen])
    assert q["passed"], q["reasons"]
    assert {"mass significance (three-step)", "mass three-step vs general", "cog three-step vs general"} <= {
        c["check"] for c in q["checks"]}
    biased = dataclasses.replace(ts, mass_kg=ts.mass_kg * 1.04)  # a 4 % bias, as one-way friction gives
    q = evaluate(deltas, kin, biased, others=[gen])
    assert "mass three-step vs general" in failed(q)
    with pytest.raises(QualityGateError, match="three-step mass"):
        require_passed(RunResult("sim-ec66", "runs/x", biased, [gen], quality=q))
