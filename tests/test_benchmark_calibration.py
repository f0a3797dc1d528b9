"""benchmarks.calibration: a cell of several noise draws per case is judged on the cases it is worth."""

import numpy as np

from benchmarks.calibration import cell, chance

CHI2_3_95 = 7.814728


def _rows(rng, cases, draws, shared):
    """One cell under an exactly right σ: z = √shared·s_case + √(1 − shared)·e_draw per quantity."""
    rows = []
    for k in range(cases):
        s = rng.standard_normal(4)
        for _ in range(draws):
            z = np.sqrt(shared) * s + np.sqrt(1.0 - shared) * rng.standard_normal(4)
            rows.append({"payload": k, "z_mass": z[0], "z_cog": list(z[1:]), "mass_err_g": z[0],
                         "cog_err_mm": float(np.linalg.norm(z[1:])), "cog_in_ci95": bool(z[1:] @ z[1:] <= CHI2_3_95)})
    return rows


def test_independent_draws_count_whole_and_repeated_draws_count_once():
    rng = np.random.default_rng(3)
    free = cell(_rows(rng, 200, 3, 0.0))
    assert free["draws"] == 3 and all(540 <= n <= 600 for n in (free["n_m"], *free["n_xyz"]))
    same = cell(_rows(rng, 200, 3, 0.999))
    assert all(195 <= n <= 215 for n in (same["n_m"], *same["n_xyz"]))
    assert same["n_cover_m"] < 215 and same["n_cover_c"] < 215


def test_a_right_sigma_with_a_shared_part_is_rarely_called_unlikely():
    """24 cases × 3 draws, 70 % of the variance shared: counted as 72 independent cases, a right σ would be called
    unlikely (chance < 0.05) 23 % of the time."""
    rng = np.random.default_rng(4)
    low = [chance(cell(_rows(rng, 24, 3, 0.7))) < 0.05 for _ in range(300)]
    assert np.mean(low) <= 0.08
