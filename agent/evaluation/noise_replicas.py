"""The run's own noise estimate replayed on simulated noise of one planned sweep: how far it scatters (issue 22).

``noise_scatter`` sizes the scatter of the noise σ a run reports from the planned rows. Two things it took as fixed
are chance in a run, and this module measures them by running the run's estimator (``solvers.wls.fit``'s rules) on
replicas of white effort noise passed through the angle matching the run will do:

- **the deltas' correlation**: each delta is a loaded sample minus the empty run interpolated at its angle, and a
  combined sample half of each leg interpolated at the grid (``analysis.delta``, ``analysis.combine``); where the
  legs' samples fall against the grid is chance (and the empty run's against the loaded run's: ``EMPTY_PHASE``). Correlated rows carry fewer effective samples: a group's
  residual variance scatters as 2·Σᵢⱼ Cᵢⱼ²/(tr C)² (C the rows' noise covariance), not 2/m (sim-ec66, j2_triple
  7 %: 1.15× the variance).
- **the Sokal window** the run picks from its residuals (``wls.autocorrelation_time``): on sim-ec66's combined
  sweeps τ comes out 1.4–1.6 and the window 4–19 lags, against the fixed 6 taken before; and the window is chosen
  from the same residuals whose kernel ratio it then sets, so a long window comes with a high ratio. Over 60 seeded
  recordings the ratio's standard deviation was 0.19–0.21 per sweep with the run's window, 0.16–0.18 at a fixed 6,
  and 0.19–0.21 again at a fixed 8 (the runs' mean): the windows' level matters, the choice from the data hardly.

Each replica draws where each leg's samples fall against ``combine_pair``'s grid (one sample's spacing, uniform;
the empty run's against the loaded run's: ``EMPTY_PHASE``), builds the rows' noise map with the analysis' own
functions, draws the joints' white noise through it and applies the run's window rule to the normalised residuals.
``noise_scatter`` then takes the kernel ratio's scatter at each replica's window (``kernel_ratio``: from the planned
rows' scores) and the groups' at 2f/m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from payload_agent.solvers import wls

REPLICAS = 64  # per sweep
REPLICA_SEED = 19
MIN_SAMPLES = 24  # the shortest sweep replayed (the analysis refuses fewer than 20 overlapping samples)
# where the empty run's samples fall against the loaded run's, in sample spacings: both runs are the same commanded
# profile sampled on the controller's cycle, so at the same angles (the simulated controllers: the interpolation's
# larger weight 0.97-1.00 in every sweep of sim-ec66's seeded runs). A stream not synchronous with the motion would
# put it anywhere (uniform: f 1.25 and windows of 9 lags on average on j2_triple 7 %, against 1.15 and 7-8 locked)
EMPTY_PHASE = 0.0


@dataclass(frozen=True)
class SweepReplicas:
    """What the replicas of one sweep showed: the window the run's rule picked in each, and ``dof_factor``
    f = m·Σ C²/(tr C)² averaged (a group's σ̂² scatters as 2f/m, C the rows' noise covariance)."""

    windows: tuple[int, ...]
    dof_factor: float


def noise_map(lo: float, hi: float, n: int, both: bool, rng: np.random.Generator):
    """The (n, sources) noise map of a planned sweep of n samples over [lo, hi] (one joint's angle) for one draw of
    where the loaded and the empty run's samples fall: ``analysis.delta.subtract``'s, then for a bidirectional sweep
    ``analysis.combine.combine_pair``'s on the grid."""
    from payload_agent.analysis.combine import _noise_map as combined_map
    from payload_agent.analysis.delta import _noise_map as delta_map

    h = (hi - lo) / max(n - 1, 1)

    def leg() -> tuple[np.ndarray, object]:
        phase = rng.uniform()
        x = lo + h * (np.arange(n) + phase)  # the loaded samples, one leg
        xe = lo + h * (np.arange(-1, n + 1) + phase + EMPTY_PHASE)  # the empty run's, around them
        x = x[x <= hi + 1e-12 * h]
        return x, delta_map(x, xe)

    if not both:
        return leg()[1]
    legs = [leg(), leg()]  # ``combine_pair``'s grid: the legs' overlap, as many points as the sparser leg has there
    a, b = max(x[0] for x, _ in legs), min(x[-1] for x, _ in legs)
    count = min(int(np.sum((x >= a) & (x <= b))) for x, _ in legs)
    return combined_map(np.linspace(a, b, count), legs)


def effective_factor(noise) -> float:
    """f = m·Σ C²/(tr C)² of rows whose noise map is ``noise`` ((m, sources), C = N·Nᵀ): a mean square of those
    rows scatters as 2f/m (1 for independent rows of equal noise)."""
    S = (noise @ noise.T).tocoo()
    return S.shape[0] * float(np.sum(S.data ** 2)) / float(np.sum(S.diagonal())) ** 2


def replay(n: int, both: bool, joints: int, replicas: int = REPLICAS, seed: int = REPLICA_SEED) -> SweepReplicas:
    """The run's Sokal windows and the rows' effective-sample factor on ``replicas`` draws of white noise for a
    sweep of ``n`` planned samples with ``joints`` joints' rows (the normalised residuals summed per instant, as
    ``wls.fit`` forms the series it takes τ from). Depends on (n, both, joints) alone: cached, n taken to the
    nearest step of 2^¼ (±9 %: the windows' spread moves as 1/√n, by ±4.5 % across a step), so that the plan's
    candidates share replicas (about 0.5 s each)."""
    n = max(MIN_SAMPLES, int(round(2.0 ** (round(4.0 * math.log2(max(n, 1))) / 4.0))))
    key = (n, bool(both), int(joints), int(replicas), int(seed))
    if key not in _CACHE:
        rng = np.random.default_rng(seed)
        windows, dof = [], []
        for _ in range(replicas):
            N = noise_map(0.0, 1.0, n, both, rng)
            m = N.shape[0]
            dof.append(effective_factor(N))
            e = N @ rng.standard_normal((N.shape[1], joints))
            z = (e / np.sqrt(np.mean(e ** 2, axis=0))).sum(axis=1)
            windows.append(wls.autocorrelation_time(z, max_lag=max(1, int(wls.HAC_MAX_FRACTION * m)))[1])
        _CACHE[key] = SweepReplicas(tuple(int(w) for w in windows), float(np.mean(dof)))
    return _CACHE[key]


_CACHE: dict[tuple, SweepReplicas] = {}


__all__ = ["REPLICAS", "SweepReplicas", "noise_map", "effective_factor", "replay"]
