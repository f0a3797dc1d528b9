"""benchmarks/effort_noise.py: the per-joint current noise it reports is the noise put into a moving recording."""

from __future__ import annotations

import numpy as np

from benchmarks.effort_noise import measure
from benchmarks.realdata import MAMEDOV_COLUMNS

NOISE_A = np.array([0.2, 0.18, 0.15, 0.05, 0.06, 0.03])


def _write_log(path, noise_a: np.ndarray, seed: int = 4) -> None:
    """A headerless log in the ur10e-mamedov layout: smooth excitation, ~100 Hz with 8–12 ms jitter, one rubbish row."""
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.cumsum(rng.choice([0.008, 0.010, 0.012], size=3000, p=[0.1, 0.8, 0.1]))
    w = 2 * np.pi * np.array([0.11, 0.07, 0.13, 0.17, 0.23, 0.19])
    q = 0.8 * np.sin(w * (t[:, None] - t[0]) + np.arange(6))
    qd = 0.8 * w * np.cos(w * (t[:, None] - t[0]) + np.arange(6))
    amplitude_a = np.array([2.0, 2.0, 2.0, 0.5, 0.5, 0.5])  # the real arm's wrist currents are a few tenths of an A
    target = amplitude_a * np.sin(w * (t[:, None] - t[0]) + 0.5) + 0.3 * np.tanh(qd / 0.01)  # friction jumps at reversals
    actual = target + rng.normal(size=target.shape) * noise_a
    rows = np.hstack([t[:, None], q, qd, actual, target, 10 * target])
    lines = ["999.0," + ",".join(["0"] * 12 + ["5e6"] * 18)]  # a recorder attaching: not a reading, dropped
    lines += [",".join(f"{v:.6f}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")


def test_recovers_the_noise_put_into_a_moving_recording(tmp_path):
    log = tmp_path / "log.csv"
    _write_log(log, NOISE_A)
    r = measure(log, MAMEDOV_COLUMNS, half=5, min_speed=0.05)
    assert r.dropped == 1
    np.testing.assert_allclose(r.local_fit_a, NOISE_A, rtol=0.1)
    np.testing.assert_allclose(r.actual_minus_target_a, NOISE_A, rtol=0.1)
    # independent noise: about 1 row to row (the signal's own 10 ms change adds a little)
    assert np.all(np.abs(r.whiteness[0] - 1.0) < 0.15), r.whiteness[0]


def test_a_noise_free_moving_recording_reports_almost_no_noise(tmp_path):
    log = tmp_path / "log.csv"
    _write_log(log, np.zeros(6))
    r = measure(log, MAMEDOV_COLUMNS, half=5, min_speed=0.05)
    # the motion and the friction steps at reversals are not taken for noise (file rounding is 1e-6 A)
    assert np.all(r.local_fit_a < 0.005), r.local_fit_a
