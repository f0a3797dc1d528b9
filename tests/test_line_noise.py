"""The long-run noise variance does not count a periodic-in-angle torque that averages out of the estimate.

A strain-wave gear's mesh ripple on a turning joint is a sinusoid in its angle, about 30 periods over a sweep:
it averages out of the estimate, but a kernel estimate whose bandwidth follows the residuals' autocorrelation
read it as correlated noise (σ 2–3 × too wide on realistic+ripple at 1 %, docs/benchmarks.md, session 25).
These tests draw synthetic sweep rows many times and compare the reported σ with the estimates' real scatter,
with the ripple (white noise under it) and with genuinely correlated noise (AR(1)), whose σ must stay.
"""

from __future__ import annotations

import numpy as np

from payload_agent.solvers import three_step, wls

N_SAMPLES = 3000  # one slow sweep
SWEEP_RAD = 1.0  # 57°: 2·100·1 rad = 32 mesh periods, about 94 samples a period
MESH = 2 * 100  # the arm's mesh frequency in cycles per radian × 2π; the agent is not told it
THETA = np.array([12.0, -3.0])
NOISE_NM = 0.05
RIPPLE_NM = 0.2
DRAWS = 150


def _rows(rng: np.random.Generator, noise: np.ndarray, ripple: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q = np.linspace(0.3, 0.3 + SWEEP_RAD, N_SAMPLES)
    Y = np.column_stack([np.cos(q), np.sin(q)])
    tau = Y @ THETA
    y = tau + noise
    if ripple:  # the mesh ripple, its amplitude following the torque, a phase of this arm's
        y = y + RIPPLE_NM * (1.0 + 0.02 * np.abs(tau)) * np.sin(MESH * q + rng.uniform(0, 2 * np.pi))
    return q, Y, y


def _ar1(rng: np.random.Generator, rho: float) -> np.ndarray:
    e = rng.standard_normal(N_SAMPLES) * NOISE_NM * np.sqrt(1 - rho ** 2)
    out = np.empty(N_SAMPLES)
    x = rng.standard_normal() * NOISE_NM
    for i in range(N_SAMPLES):
        x = rho * x + e[i]
        out[i] = x
    return out


def _fit_ratios(make_noise, ripple: bool) -> np.ndarray:
    """Mean reported σ over the estimates' scatter, per parameter, over ``DRAWS`` draws (two sweeps a fit)."""
    rng = np.random.default_rng(5)
    thetas, stds = [], []
    for _ in range(DRAWS):
        groups = []
        for s in ("up", "down"):
            _, Y, y = _rows(rng, make_noise(rng), ripple)
            groups.append(wls.Group(s, s, Y, y, joint=1))
        res = wls.fit(groups)
        thetas.append(res.theta)
        stds.append(res.std)
    return np.mean(stds, axis=0) / np.std(thetas, axis=0)


def test_a_mesh_ripple_that_averages_out_is_not_read_as_noise_by_the_general_fit():
    white = _fit_ratios(lambda rng: rng.standard_normal(N_SAMPLES) * NOISE_NM, ripple=True)
    # main (the lines left in): 5.7 / 5.3, the ripple's power leaked into the zero-frequency estimate
    assert np.all(white > 0.8) and np.all(white < 1.25), white


def test_a_genuinely_correlated_noise_keeps_its_sigma_with_and_without_the_ripple():
    ar = _fit_ratios(lambda rng: _ar1(rng, 0.95), ripple=False)
    both = _fit_ratios(lambda rng: _ar1(rng, 0.95), ripple=True)
    assert np.all(ar > 0.8) and np.all(ar < 1.3), ar
    assert np.all(both > 0.8) and np.all(both < 1.3), both  # main (the lines left in): 2.6 / 2.2


def test_the_three_step_covariance_does_not_read_the_ripple_as_noise():
    """``three_step._covariance`` on one sweep's smooth sensitivities J (4 × n): σ against the scatter of J·r."""
    rng = np.random.default_rng(8)
    q = np.linspace(0.3, 0.3 + SWEEP_RAD, N_SAMPLES)
    J = np.vstack([np.cos(q), np.sin(q), q - q.mean(), np.ones_like(q)]) / N_SAMPLES
    pred = 12.0 * np.cos(q)
    errs, stds = [], []
    for _ in range(DRAWS):
        r = rng.standard_normal(N_SAMPLES) * NOISE_NM + RIPPLE_NM * np.sin(MESH * q + rng.uniform(0, 2 * np.pi))
        errs.append(J @ r)
        cov = three_step._covariance({"b2": J}, {"b2": (pred + r, pred, 1)}, None)
        stds.append(np.sqrt(np.diag(cov)))
    ratio = np.mean(stds, axis=0) / np.sqrt(np.mean(np.square(errs), axis=0))
    # main (the lines left in): 4.7–11
    assert np.all(ratio > 0.8) and np.all(ratio < 1.25), ratio
