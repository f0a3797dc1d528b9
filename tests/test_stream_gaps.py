"""Stream gaps (a busy host's simulated stream, a congested network): the deltas keep every sample and carry
how each one's noise is made (``DeltaSweep.noise_map``), so that the fit's covariance counts an error shared
by a run of samples interpolated across one gap once, not as many independent observations (issue 22)."""

import numpy as np
from scipy import sparse

from benchmarks.cable_false_alarms import kept
from payload_agent.analysis.combine import combine_pair
from payload_agent.analysis.delta import DeltaSweep, subtract
from payload_agent.recording.rundata import SweepData
from payload_agent.solvers.wls import Group, fit
from payload_agent.types import SweepKey

SPEED_RAD_S = 0.2
TICK_S = 0.002
THETA = np.array([0.3, 2.0, -1.5])  # offset, sin and cos amplitude of the torque on joint 2, N·m
NOISE_NM = 0.5


def _thin(n: int, rng: np.random.Generator, gap_rate: float) -> np.ndarray:
    """Which of n samples a stream with gaps keeps (``benchmarks.cable_false_alarms.kept``), its ends recorded."""
    keep = kept(n, rng, gap_rate)
    keep[:5] = keep[-5:] = True  # the sweep's ends are recorded (the windows must overlap)
    return keep


def _run(direction: str, loaded: bool, rng: np.random.Generator, gap_rate: float) -> SweepData:
    t = np.arange(0.0, 0.3 / SPEED_RAD_S, TICK_S)
    x = SPEED_RAD_S * t if direction == "up" else 0.3 - SPEED_RAD_S * t
    keep = _thin(len(t), rng, gap_rate)
    t, x = t[keep], x[keep]
    q = np.zeros((len(t), 6))
    q[:, 1] = x
    effort = rng.normal(0.0, NOISE_NM, (len(t), 6))
    effort[:, 1] += 4.0 * np.sign(SPEED_RAD_S if direction == "up" else -SPEED_RAD_S)  # friction, cancels
    if loaded:
        effort[:, 1] += THETA[0] + THETA[1] * np.sin(x) + THETA[2] * np.cos(x)
    return SweepData(SweepKey("p", 2, direction, 10.0), t, q, effort, f"{direction} {'loaded' if loaded else 'empty'}")


def _combined(rng: np.random.Generator, gap_rate: float) -> DeltaSweep:
    legs = [subtract(_run(d, True, rng, gap_rate), _run(d, False, rng, gap_rate)) for d in ("up", "down")]
    return combine_pair(*legs)


def _chi2(d: DeltaSweep, with_map: bool) -> float:
    x = d.q[:, 1]
    Y = np.column_stack([np.ones_like(x), np.sin(x), np.cos(x)])
    res = fit([Group("p/j2", "p", Y, d.dtau[:, 1], 1, d.noise_map if with_map else None)])
    e = res.theta - THETA
    return float(e @ np.linalg.solve(res.cov, e))


def _mean_chi2(gap_rate: float, draws: int = 150) -> tuple[float, float, int]:
    rng = np.random.default_rng(7)
    new, old, n = [], [], []
    for _ in range(draws):
        d = _combined(rng, gap_rate)
        new.append(_chi2(d, True))
        old.append(_chi2(d, False))
        n.append(len(d.q))
    return float(np.mean(new)), float(np.mean(old)), int(np.median(n))


def test_gappy_stream_chi2_is_calibrated_where_the_kernel_alone_was_not():
    # gap rate 0.05 keeps about half of each run's samples, as the loaded host's simulated UR did; the
    # estimate's χ² against the truth has p = 3 degrees of freedom; the old covariance (no noise map:
    # Bartlett kernel on the residuals alone) counted each gap's shared interpolation error many times
    new, old, n = _mean_chi2(0.05)
    assert 2.3 < new < 3.8, new
    assert old > 1.4 * new, (old, new)
    assert n > 150  # no sample dropped: the combined grid has the sparser leg's count


def test_dense_stream_chi2_stays_calibrated():
    new, old, n = _mean_chi2(0.0, draws=100)
    assert 2.3 < new < 3.8, new
    assert n > 700


def test_noise_map_reproduces_the_combined_noise():
    """The combined sweep's map applied to its sources (each leg's samples, in angle order) gives its Δτ."""
    rng = np.random.default_rng(3)
    xu = np.sort(rng.uniform(0.0, 0.3, 200))
    xd = np.sort(rng.uniform(0.0, 0.3, 90))

    def leg(direction, x):
        q = np.zeros((len(x), 6))
        q[:, 1] = x
        return DeltaSweep(SweepKey("p", 2, direction, 10.0), q, rng.normal(size=(len(x), 6)), SPEED_RAD_S)

    up, down = leg("up", xu), leg("down", xd)
    down.noise_map = sparse.identity(len(xd), format="csr")  # a leg with a map: the combination makes one
    comb = combine_pair(up, down)
    sources = np.vstack([up.dtau, down.dtau])
    assert comb.noise_map.shape == (len(comb.q), len(xu) + len(xd))
    np.testing.assert_allclose(comb.noise_map @ sources, comb.dtau, atol=1e-12)


def test_subtract_keeps_every_loaded_sample_and_maps_its_noise():
    rng = np.random.default_rng(5)
    loaded = _run("up", True, rng, 0.0)
    empty = _run("up", False, rng, 0.05)
    d = subtract(loaded, empty)
    assert len(d.q) >= len(loaded.t) - 10  # the window's ends at most, none for the empty run's gaps
    rows = d.noise_map.toarray()
    np.testing.assert_allclose(rows.sum(axis=1), 0.0, atol=1e-12)  # loaded sample minus an interpolation
    assert np.all(rows[:, :len(d.q)].diagonal() == 1.0)
