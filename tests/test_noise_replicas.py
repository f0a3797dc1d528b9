"""benchmarks.noise_replicas: the pooled rms(err/σ) splits into the noise part and the systematic part it reports."""

import numpy as np

from benchmarks.noise_replicas import summary


def _cases(rng, n_cases, draws, sigma_scale, bias_sd):
    """Per case (draws, 4, 2): errors of true spread 1, a per-case bias of sd ``bias_sd``, σ reported as sigma_scale."""
    out = []
    for _ in range(n_cases):
        bias = rng.normal(0.0, bias_sd, 4)
        err = bias + rng.normal(0.0, 1.0, (draws, 4))
        out.append(np.stack([err, np.full((draws, 4), sigma_scale)], axis=2))
    return out


def test_a_calibrated_sigma_pools_to_one_and_splits_into_its_parts():
    rng = np.random.default_rng(1)
    s = summary(_cases(rng, 400, 3, np.sqrt(1.0 + 0.5 ** 2), 0.5))  # σ covers noise and bias together
    np.testing.assert_allclose(s["rms"], 1.0, atol=0.06)
    np.testing.assert_allclose(s["noise"], 1.0 / np.sqrt(1.25), atol=0.06)
    np.testing.assert_allclose(s["systematic"], 0.5 / np.sqrt(1.25), atol=0.08)  # the mean's own noise taken out
    assert np.all(np.abs(s["in95"] - 0.95) < 0.03) and int(s["draws"]) == 1200


def test_a_sigma_twice_too_wide_shows_in_the_noise_part():
    s = summary(_cases(np.random.default_rng(2), 400, 3, 2.0, 0.0))
    np.testing.assert_allclose(s["rms"], 0.5, atol=0.03)
    np.testing.assert_allclose(s["noise"], 0.5, atol=0.03)
    assert np.all(s["systematic"] < 0.1)
