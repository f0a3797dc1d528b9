"""Combining up and down sweeps cancels friction odd in velocity, load-dependent Coulomb included."""

from __future__ import annotations

import numpy as np
import pytest

from payload_agent.analysis.combine import COMBINED, add_combined, combine_pair
from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.types import SweepKey
from payload_agent.solvers import general, regressor, three_step

from test_general_solver import THETA, TRUTH_C, TRUTH_M, planned_sweeps

COULOMB = np.array([0.0, 4.0, 3.0, 1.0, 1.0, 0.5])
LOAD_RATIO = 0.05


def friction_deltas(sweeps, kin, noise=0.0, rng=None):
    """Δτ = Y·θ + sign(v)·(c + k·|Y·θ|) on the moving joint (the others stand still)."""
    out = {}
    for key, q in sweeps:
        j = key.joint - 1
        v = np.sign(q[-1, j] - q[0, j])
        dtau = np.zeros_like(q)
        for i, qi in enumerate(q):
            dtau[i, 1:] = regressor.regressor(kin, qi, range(1, 6), j, 0.025) @ THETA  # gravity + centripetal
        dtau[:, j] += v * (COULOMB[j] * 0.1 + LOAD_RATIO * np.abs(dtau[:, j]))  # what the baseline missed
        if noise:
            dtau += rng.normal(0.0, noise, dtau.shape)
        out[key] = DeltaSweep(key, q, dtau, float(v) * 0.025)
    return out


@pytest.fixture(scope="module")
def data():
    config, sweeps = planned_sweeps(bidirectional=True)
    kin = config.robot.kinematics
    return kin, friction_deltas(sweeps, kin)


def test_plan_has_both_legs(data):
    _, deltas = data
    dirs = {k.direction for k in deltas}
    assert dirs == {"up", "down"}


def test_combination_cancels_friction(data):
    kin, deltas = data
    both, notes = add_combined(deltas)
    assert not notes
    combined = [k for k in both if k.direction == COMBINED]
    assert len(combined) == 4
    est = general.solve(both, kin)
    assert set(est.samples) == {k.name for k in combined}
    assert abs(est.mass_kg - TRUTH_M) < 1e-6
    assert np.max(np.abs(np.asarray(est.cog_m) - TRUTH_C)) < 1e-6


def test_one_direction_is_biased(data):
    kin, deltas = data
    up_only = {k: d for k, d in deltas.items() if k.direction == "up"}
    est = general.solve(up_only, kin)
    assert abs(est.mass_kg - TRUTH_M) > 0.02  # tens of grams of bias from the friction left over
    ts = three_step.solve(up_only, kin)
    assert abs(ts.mass_kg - TRUTH_M) > 0.02
    # without combination, the solver on both legs still works (friction partly averages out)
    plain = general.solve(deltas, kin, use_combined=False)
    assert plain.mass_kg > 0


def test_three_step_uses_combined(data):
    """With both legs recorded the three-step solver cancels the friction as the general one does."""
    kin, deltas = data
    both, _ = add_combined(deltas)
    up_only = {k: d for k, d in deltas.items() if k.direction == "up"}
    est = three_step.solve(both, kin)
    assert set(est.samples) <= {k.name for k in both if k.direction == COMBINED} | {"b-j2-both"}
    assert abs(est.mass_kg - TRUTH_M) < 1e-6
    assert np.max(np.abs(np.asarray(est.cog_m) - TRUTH_C)) < 1e-6
    # the paper's single direction stays available, and is what a one-way recording gets
    paper = three_step.solve(both, kin, directions=("up",))
    assert paper.mass_kg == three_step.solve(up_only, kin).mass_kg
    assert abs(paper.mass_kg - TRUTH_M) > 0.02


def test_three_step_uncertainty_covers_the_error(data):
    """The three-step reports a covariance; over noisy repetitions its errors match it."""
    kin, clean = data
    rng = np.random.default_rng(5)
    z = []
    for _ in range(12):
        noisy = {k: DeltaSweep(k, d.q, d.dtau + rng.normal(0.0, 0.3, d.dtau.shape), d.speed_rad_s)
                 for k, d in clean.items()}
        both, _ = add_combined(noisy)
        est = three_step.solve(both, kin)
        assert est.mass_std_kg > 0 and all(s > 0 for s in est.cog_std_m)
        assert np.asarray(est.covariance).shape == (4, 4)
        err = np.array([est.mass_kg - TRUTH_M, *(np.asarray(est.cog_m) - TRUTH_C)])
        z.append(err / np.array([est.mass_std_kg, *est.cog_std_m]))
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.5) & (rms < 1.6)), rms


def test_combined_with_noise_and_unequal_sampling(data):
    kin, _ = data
    config, sweeps = planned_sweeps(bidirectional=True)
    rng = np.random.default_rng(3)
    # the down legs sampled more densely and over a slightly shifted range: interpolation must cope
    resampled = []
    for key, q in sweeps:
        if key.direction == "down":
            s = np.linspace(0.0, 1.0, 331)[:, None]
            q = q[0] + s * (q[-1] - q[0]) * 0.97
        resampled.append((key, q))
    deltas = friction_deltas(resampled, kin, noise=0.1, rng=rng)
    both, notes = add_combined(deltas)
    assert not notes
    est = general.solve(both, kin)
    assert abs(est.mass_kg - TRUTH_M) < 4 * est.mass_std_kg + 1e-3
    assert np.all(np.abs(np.asarray(est.cog_m) - TRUTH_C) < 4 * np.asarray(est.cog_std_m) + 5e-4)


def test_mismatched_pair_refused(data):
    _, deltas = data
    keys = list(deltas)
    a = deltas[SweepKey("b", 2, "up", keys[0].speed_percent)]
    b = deltas[SweepKey("b", 3, "down", keys[0].speed_percent)]
    with pytest.raises(DataError):
        combine_pair(a, b)
