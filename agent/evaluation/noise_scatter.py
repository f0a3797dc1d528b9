"""How much the noise term a run reports scatters from run to run: part of the plan's draws of the reported σ.

A run does not know its noise; it estimates it (``solvers.wls.fit``), and the σ it reports moves with that
estimate. ``plan --target-std`` predicts the σ of a typical run and the chance that a run reports more than the
target (``design.Prediction.p_over``); without this scatter that chance held only the wrist term's (issue 22: 4 of
10 runs reported 2.00–2.07 g against a 2 g target where the plan said 0 %). Two parts of the run's estimate
scatter, both sized here from the planned rows as the run's fit forms them:

- **each group's residual variance** σ̂²_g (one group: one joint's rows in one sweep, ``wls.Group``), the mean
  square of its m_g residuals: relative variance 2/m_g. The run's noise variance of a quantity a·θ is a sum over
  the groups of share_g·σ̂²_g/σ²_g, so it moves by Σ share_g·δ_g.
- **each sweep's kernel ratio** (``wls.modelled_excess``): the rows' noise map is scaled up by max(ratio, 1),
  where ratio is the lag-window (Bartlett, window L) estimate of the scores' long-run variance over the map's,
  averaged over the parameters. On noise the map describes, it is 1 on average with a relative variance of the
  kernel estimate, 2·K/m_eff (K = 1 + 2·Σ_{l≤L}(1 − l/(L+1))², m_eff the sweep's effective number of equally
  weighted score instants), and the run keeps it only above 1. L follows the residuals' autocorrelation time
  τ (Sokal's window, L ≥ ``HAC_WINDOW_C``·τ): ``WHITE_TAU`` on white noise after the empty run's interpolation,
  times the plan's inflation² for noise correlated in time.

Each draw takes independent standard normals for these sources (seeded, the same for every candidate: common
random numbers) and gives the factor by which the run's noise variance of the mass, and of the centre of mass's
largest axis, differs from the plan's noise term. Centred on the mean: the plan's noise term is calibrated to the
runs' mean (``noise_inflation.WHITE_RATIO`` holds the kernel ratio's average excess).

Measured (white effort noise of the simulated UR5e at 500 Hz, 30 seeds, offline recordings; docs/benchmarks.md
"Session 15"): the run's robust σ scattered 1.7 % (mass) and 2.8 % (CoM) on j2_quarter 5 %, 0–20°, and 3.1 % /
4.6 % on j2_pair 12 %, 0–15°; ``tests/test_noise_scatter.py`` checks the model against such seeds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.solvers import wls

# the integrated autocorrelation time of a run's normalised residuals on white noise: the empty run interpolated
# onto the loaded run's angles correlates neighbouring deltas (30 seeds of the simulated UR5e: 1.0–1.6 per sweep)
WHITE_TAU = 1.2
# the draws (``planned_terms.DRAWS`` of them) come from their own seeded stream, column by column, so that every
# candidate's first sources get the same normals whatever its number of groups
SCATTER_SEED = 15
_MEAN_POSITIVE_PART = 1.0 / math.sqrt(2.0 * math.pi)  # E[max(z, 0)] for a standard normal z


def kernel_factor(bandwidth: int) -> float:
    """K = Σ_{|l| ≤ L} k(l)² of the Bartlett kernel k(l) = 1 − |l|/(L+1): the kernel estimate's variance over a
    plain mean square's, per effective sample."""
    return 1.0 + 2.0 * sum((1.0 - lag / (bandwidth + 1.0)) ** 2 for lag in range(1, bandwidth + 1))


def window(samples: int, inflation: float) -> int:
    """The run's lag window for a sweep of ``samples`` instants (``wls.autocorrelation_time``'s rule)."""
    tau = WHITE_TAU * max(float(inflation), 1.0) ** 2
    cap = max(1, int(wls.HAC_MAX_FRACTION * samples))
    return min(cap, max(1, math.ceil(wls.HAC_WINDOW_C * tau)))


@dataclass(frozen=True)
class NoiseScatter:
    """The relative deviation of the run's noise variance from the plan's, per draw: (draws, 2) for the mass and
    the centre of mass (largest axis). ``relative_std``: their standard deviations (of the variance)."""

    deviation: np.ndarray = dataclasses.field(compare=False, repr=False)
    relative_std: tuple[float, float] = (0.0, 0.0)

    def factors(self) -> np.ndarray:
        """The run's noise variance over the plan's, per draw (never below 0)."""
        return np.maximum(1.0 + self.deviation, 0.0)

    def over(self, runs: int) -> "NoiseScatter":
        """The same for ``runs`` repetitions averaged (each run's estimate is independent)."""
        s = 1.0 / math.sqrt(runs)
        return NoiseScatter(self.deviation * s, (self.relative_std[0] * s, self.relative_std[1] * s))


def none(draws: int) -> NoiseScatter:
    return NoiseScatter(np.zeros((draws, 2)))


def _normals(draws: int, columns: int) -> np.ndarray:
    rng = np.random.default_rng(SCATTER_SEED)
    return np.column_stack([rng.standard_normal(draws) for _ in range(columns)]) if columns else np.zeros((draws, 0))


def scatter(groups: Sequence[wls.Group], w: np.ndarray, inv: np.ndarray, directions: np.ndarray, inflation: float,
            draws: int) -> NoiseScatter:
    """The scatter of the run's noise variance of the quantities a·θ (``directions``: (2, p) rows a for the mass
    and the CoM's largest axis) for the planned rows ``groups`` with white weights ``w`` and (YᵀWY)⁻¹ ``inv``."""
    groups = list(groups)
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    p = inv.shape[0]
    sweeps = list(dict.fromkeys(g.sweep for g in groups))
    n_src = len(groups) + len(sweeps)
    loads = np.zeros((n_src, len(directions)))  # each source's share times its relative std, per quantity
    positive = np.zeros(n_src, bool)  # the sweeps' ratios: kept only above 1
    contrib = {}  # (group index) -> (rows, p + q) per-row variance contributions for the unit and quantity directions
    unit = np.vstack([np.eye(p), directions])
    totals = np.einsum("ij,jk,ik->i", unit, inv, unit)
    for i, g in enumerate(groups):
        ww = w[starts[i]:starts[i + 1]]
        contrib[i] = (g.Y @ inv @ unit.T) ** 2 * ww[:, None]
        share = contrib[i][:, p:].sum(axis=0) / np.maximum(totals[p:], 1e-300)
        loads[i] = share * math.sqrt(2.0 / max(len(g.y), 1))
    for s, name in enumerate(sweeps):
        members = [i for i, g in enumerate(groups) if g.sweep == name]
        per_instant = sum(contrib[i] for i in members)  # the joints of one instant share its score
        m = per_instant.shape[0]
        m_eff = per_instant.sum(axis=0) ** 2 / np.maximum((per_instant ** 2).sum(axis=0), 1e-300)
        ratio_var = float(np.mean(2.0 * (kernel_factor(window(m, inflation)) - 1.0) / np.maximum(m_eff[:p], 1.0)))
        share = per_instant[:, p:].sum(axis=0) / np.maximum(totals[p:], 1e-300)
        loads[len(groups) + s] = share * math.sqrt(ratio_var)
        positive[len(groups) + s] = True
    z = _normals(draws, n_src)
    z[:, positive] = np.maximum(z[:, positive], 0.0) - _MEAN_POSITIVE_PART
    var_z = np.where(positive, 0.5 - 1.0 / (2.0 * math.pi), 1.0)
    rel_std = np.sqrt(np.sum(loads ** 2 * var_z[:, None], axis=0))
    return NoiseScatter(z @ loads, (float(rel_std[0]), float(rel_std[1])))


__all__ = ["WHITE_TAU", "kernel_factor", "window", "NoiseScatter", "none", "scatter"]
