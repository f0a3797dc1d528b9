"""The data-sized terms predicted before a run (agent/evaluation/planned_terms.py): their expectations are what a
run's own rule gives on average, checked against that rule applied to random draws."""

import numpy as np
import pytest

from payload_agent.evaluation import planned_terms
from payload_agent.evaluation.systematics import friction


def test_shrunk_share_is_the_mean_of_the_wrist_terms_rule():
    rng = np.random.default_rng(3)
    D = np.diag([4.0, 1.0, 0.25, 0.01])
    spread = planned_terms.SPREAD_RATIO
    z = rng.standard_normal((200_000, 4)) * np.sqrt(spread * np.diag(D))
    q = np.sum(z ** 2 / np.diag(D), axis=1)
    s2 = np.maximum(q - 4, 0.0) / q  # offsets.shrink, r = rank D = 4
    mean_term = np.mean(s2[:, None] * z ** 2, axis=0)
    assert mean_term == pytest.approx(planned_terms.shrunk_share(4) * np.diag(D), rel=0.03)
    assert planned_terms.shrunk_share(4, 1.0) == pytest.approx(0.2707, abs=1e-3)
    assert planned_terms.shrunk_share(0) == 0.0


@pytest.mark.parametrize("truth_nm", [0.0, 0.3])
def test_expected_change_square_is_the_mean_of_the_runs_combination(truth_nm):
    prior, meas = 0.4 ** 2, 0.15 ** 2
    rng = np.random.default_rng(5)
    # the run: friction.coulomb_change on a measurement of the true change with noise of variance ``meas``
    draws = truth_nm + rng.standard_normal(20_000) * np.sqrt(meas)
    rms2 = []
    for d in draws[:4000]:
        lo = friction.FrictionGap(0.0, 0.0, float(d), float(np.sqrt(meas / 2)), 0.0)
        em = friction.FrictionGap(0.0, 0.0, 0.0, float(np.sqrt(meas / 2)), 0.0)
        rms2.append(friction.coulomb_change([lo], [em], np.sqrt(prior)).rms_nm ** 2)
    expected = planned_terms.expected_change_square(prior, meas, truth_nm ** 2)
    assert np.mean(rms2) == pytest.approx(expected, rel=0.05)
    # under the prior itself the expectation is the prior; a short sweep (no measurement) reports the prior
    assert planned_terms.expected_change_square(prior, meas, prior) == pytest.approx(prior)
    assert planned_terms.expected_change_square(prior, float("inf"), 0.0) == prior


def test_an_earlier_measurement_of_no_change_lowers_the_predicted_friction_term():
    """On 55° sweeps the run measures the change; knowing from an earlier run that it was ~0 predicts a smaller
    term than the declared prior, on 15° sweeps (nothing measurable) the same."""
    import yaml

    from conftest import ROOT
    from payload_agent.configuration.config import parse_config
    from payload_agent.evaluation import design
    from payload_agent.solvers import general

    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text()), source="sim-ur5e.yaml")
    theta = design.nominal_theta(2.5, (30.0, -20.0, 60.0))
    known = planned_terms.FrictionKnowledge({1: 0.02, 2: -0.01}, {1: 0.1, 2: 0.1}, "test")
    decl = config.robot.joints
    out = {}
    for hi in (15.0, 55.0):
        plan = design.plan_for(config, design.Candidate(10.0, 25.0, 0.0, hi, 1, 100.0, "j2_triple"))
        sweeps = design.planned_sweeps(plan, 0.002)
        groups = general.build_groups(sweeps, config.robot.kinematics)
        w = np.concatenate([np.full(len(g.y), 1.0 / 2.0 ** 2) for g in groups])
        args = (sweeps, groups, w, theta, float(decl.friction_asymmetry_std), float(decl.friction_change_std),
                {1: 6.0, 2: 4.0}, (2.0,) * 6, 1.0)
        out[hi] = [planned_terms.friction_covariance(*args, known)[0, 0],
                   planned_terms.friction_covariance(*args, None)[0, 0]]
    assert out[55.0][0] < 0.6 * out[55.0][1]
    assert out[15.0][0] == pytest.approx(out[15.0][1], rel=0.25)
