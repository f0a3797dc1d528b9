"""``benchmarks.sigma_budget`` takes apart the σ the analysis reports: on the analysis' own deltas.

The hard scenario's mesh ripple leaves gain errors of 0.5–1.2 % on the still joints 2 and 3; the calibration stores
them per standing angle and the analysis takes them off the tool run's rows standing there (``calibration_clusters``,
in ``systematics.prepare`` through ``analyse.prepared_run``). A budget built on the uncorrected deltas explained
another estimate than the one the product reports (hard 10 %, case 5: +9.44 g against the analysis' +3.64 g).
"""

from __future__ import annotations

import pytest

from benchmarks import cases, sigma_budget
from benchmarks.remedies import comp_estimate


def test_the_budget_explains_the_estimate_and_the_sigma_the_analysis_reports():
    """Hard 10 %, case 5 of 24 (joint 2 at −90°: ε̂ +1.2 %): the budget's mass error is the analysis' (general-bi-cal-comp)
    to 1e-6 g and its total σ within 1 % (the budget's DH-length part is its own)."""
    proc = cases.Procedure("10", 10.0, cases.SPEED_ROW_TRAVEL, cases.SPEED_ROW_ACCEL, *cases.SWEEP_DEG)  # --speed 10
    budget = sigma_budget.budget("hard", 5, proc, 24)
    c = sigma_budget.analysed_case("hard", 5, proc, 24)
    assert c["prepared"].still_scales  # the run stands at the calibration's angles
    est, _ = comp_estimate(c["loaded"], c["empty"], c["ref"], c["draws"]["declared"], c["config"],
                           cases.declared_unfitted_gain_std("hard"),
                           {"length_std_m": cases.declared_length_std_mm("hard") / 1000.0}, mount_rad=c["mount"])
    assert budget["error"] == pytest.approx(1000.0 * (est.mass_kg - c["mass"]), abs=1e-6)
    assert budget["total"] == pytest.approx(1000.0 * est.mass_std_kg, rel=0.01)
