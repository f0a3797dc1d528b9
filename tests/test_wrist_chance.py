"""The tool-cable term below its presence test: the measured effect's share beyond noise, not its uncertainty too.

Offline runs of the simulated EC66 (``fakes.offline.record_plan``) as ``tests/test_cable_spring.py`` records them: an
arm without a cable whose run's test statistic lands between its null mean and its 95 % quantile (seed 3: a chance
term), and an arm with a cable the test finds. The plain fit's error does not contain the noise of the spring's
stiffnesses (``cable_spring.shares``), so below the test σ gets w·β̂β̂ᵀ (rank one), not w·(β̂β̂ᵀ + D); where the
test finds a cable, β̂β̂ᵀ; where the YAML declares one, θ̂ loses the posterior mean's effect and σ holds its spread.
"""

from __future__ import annotations

import numpy as np
import pytest

from payload_agent.evaluation import systematics
from payload_agent.evaluation.systematics import cable_spring, offsets
from payload_agent.solvers import general
from payload_agent.solvers.fitted import ALL

from test_cable_spring import CABLE_NM_PER_RAD, _record, _spring


@pytest.fixture(scope="module")
def runs():
    return {"clean": _record(None, seed=3), "cable": _record(CABLE_NM_PER_RAD)}


def _labels(model):
    return sorted({offsets.wrist_joint(g, d) for g in model.groups for d in model.sweeps if d.key.name == g.sweep}
                  - {None})


def _lever_effects(model, s):
    """A·M: the spring's stiffnesses' effect on the combined fit's θ."""
    res = model.fit(ALL)
    sens = offsets.offset_sensitivities(list(model.sweeps), model.groups_of(ALL), res.weights, res.normal_inverse,
                                        offsets.wrist_joint)
    return np.column_stack([sens[lab] for lab in _labels(model)]) @ s.levers


def _term_and_parts(kin, loaded, empty, mount):
    """(the tool-cable term's covariance of the combined fit, the spring, β̂ = A·M·κ*, D = A·M·C·MᵀAᵀ)."""
    prep, model, s = _spring(kin, loaded, empty, mount)
    syst = systematics.evaluate(prep, kin, systematics.RIGID, terms=[systematics.wrist_terms], model=model)
    AM = _lever_effects(model, s)
    return syst.covariance(), s, AM @ s.stiffness_nm_per_rad, AM @ s.cov @ AM.T


def test_below_the_test_the_term_is_the_measured_effects_share_alone(runs):
    cov, s, beta, D = _term_and_parts(*runs["clean"])
    assert not s.present and 0.2 < s.weight < 0.9  # a chance term on an arm without a cable
    scale = float(np.max(np.abs(cov)))
    assert np.allclose(cov, s.weight * np.outer(beta, beta), rtol=1e-6, atol=1e-9 * scale)
    assert np.linalg.matrix_rank(cov, tol=1e-6 * scale) == 1
    # the rule before: w·(β̂β̂ᵀ + D), D the noise of κ̂ that the plain fit's error does not contain
    assert cov[0, 0] < s.weight * (beta[0] ** 2 + D[0, 0]) - 0.1 * s.weight * D[0, 0]


def test_a_cable_the_test_finds_is_its_measured_effect_alone(runs):
    """Found, the term is β̂β̂ᵀ (rank one): β̂β̂ᵀ + D, the rule until session 18, counted κ̂'s noise twice, since the
    plain fit's error does not contain it and E[β̂β̂ᵀ] = ββᵀ + D holds it once (``cable_spring.shares``)."""
    cov, s, beta, D = _term_and_parts(*runs["cable"])
    assert s.present and s.weight == 1.0
    scale = float(np.max(np.abs(cov)))
    assert np.allclose(cov, np.outer(beta, beta), rtol=1e-6, atol=1e-9 * scale)
    assert np.linalg.matrix_rank(cov, tol=1e-6 * scale) == 1
    assert np.max(np.abs(D)) > 1e-3 * scale  # the rule before, β̂β̂ᵀ + D, fails the two asserts above
    assert "found" in cable_spring.note(s) and "uncertainty" not in cable_spring.note(s)


def test_a_declared_cable_moves_the_result_by_its_fitted_effect_and_keeps_its_noise(runs):
    """Declared (``robot.tool_cable_fitted``), θ̂ loses the unconstrained κ̂'s effect A·M·κ̂ (``Term.shift``) and σ holds
    its noise A·M·C·MᵀAᵀ (full rank where the levers are): the reported θ̂'s error is e + A·M·(κ − κ̂) with e
    independent of κ̂. Until session 21 θ̂ stayed the plain fit's and σ held w·A·M·μμᵀ·MᵀAᵀ, rank one (fails there)."""
    from dataclasses import replace

    declared = replace(systematics.RIGID, tool_cable_fitted=True)
    for kin, loaded, empty, mount in (runs["cable"], runs["clean"]):
        prep = systematics.prepare(loaded, empty, declared, mount_rad=mount)
        model = general.fit_model(prep.deltas, kin)
        syst = systematics.evaluate(prep, kin, declared, terms=[systematics.wrist_terms], model=model)
        s = cable_spring.fit_spring(model, _labels(model), mount, declared=True)
        AM = _lever_effects(model, s)
        cov, spread = syst.covariance(), AM @ s.cov @ AM.T
        scale = float(np.max(np.abs(spread)))
        assert np.allclose(cov, spread, rtol=1e-6, atol=1e-9 * scale)
        assert np.linalg.matrix_rank(cov, tol=1e-6 * scale) == len(s.joints) > 1
        assert np.allclose(syst.shift(), AM @ s.estimate, rtol=1e-6, atol=1e-9 * float(np.max(np.abs(AM))))
