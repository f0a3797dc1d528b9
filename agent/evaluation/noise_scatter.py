"""How much the noise term a run reports scatters from run to run: part of the plan's draws of the reported σ.

A run does not know its noise; it estimates it (``solvers.wls.fit``), and the σ it reports moves with that
estimate. ``plan --target-std`` predicts the σ of a typical run and the chance that a run reports more than the
target (``design.Prediction.p_over``); without this scatter that chance held only the wrist term's (issue 22: 4 of
10 runs reported 2.00–2.07 g against a 2 g target where the plan said 0 %). Two parts of the run's estimate
scatter, both sized here from the planned rows as the run's fit forms them:

- **each group's residual variance** σ̂²_g (one group: one joint's rows in one sweep, ``wls.Group``), the mean
  square of its m_g residuals: relative variance 2f/m_g, f = m·Σ C²/(tr C)² the rows' effective-sample factor
  (C their noise covariance after the run's angle matching, ``noise_replicas``; 1.15 on sim-ec66's combined
  sweeps, where the run's σ̂² scattered 11.3 % against 10.7 % for 2/m; until session 19: 2/m). The run's noise variance of a quantity a·θ is a sum over
  the groups of share_g·σ̂²_g/σ²_g, so it moves by Σ share_g·δ_g.
- **each sweep's kernel ratio** (``wls.modelled_excess``): the rows' noise map is scaled up by max(ratio, 1),
  where ratio is the lag-window (Bartlett, window L) estimate of the scores' long-run variance over the map's,
  averaged over the parameters. On noise the map describes, it is 1 on average with a relative variance of the
  kernel estimate, 2·K/m_eff (K = 1 + 2·Σ_{l≤L}(1 − l/(L+1))², m_eff the sweep's effective number of equally
  weighted score instants), and the run keeps it only above 1. L follows the residuals' autocorrelation time
  τ (Sokal's window, L ≥ ``HAC_WINDOW_C``·τ), which is itself chance: the ratio is taken over the windows the
  run's rule picks on replicas of white noise through the angle matching (``noise_replicas``: 4–17 lags, 7.7 on
  average, on j2_triple 7 % on sim-ec66, where the runs picked 4–19, 7.3–8.3; until session 19 a fixed 6 from
  τ = 1.2), times the plan's inflation² for noise correlated in time; and with its lag-0 term (``kernel_ratio``).

Each draw takes independent standard normals for these sources (seeded, the same for every candidate: common
random numbers) and gives the factor by which the run's noise variance of the mass, and of the centre of mass's
largest axis, differs from the plan's noise term. Centred on the mean, which ``NoiseScatter.kept`` gives: the
ratio kept only above 1 makes the run's noise variance E[max(ratio, 1)] × its map's on average, 1.06 on j2_triple 7 %,
0–15° on sim-ec66 and 1.03 on the calibration's paper_bd 5 %, 0–55° (the plan's noise term carries the candidate's, and
``noise_inflation`` takes the calibration run's out of what it measured; until session 19 that run's stood for every
candidate's: the plan's median 1–3 % under the runs' on the short sweeps, docs/benchmarks.md "Session 18").

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

from payload_agent.evaluation import noise_replicas
from payload_agent.solvers import wls

# the draws (``planned_terms.DRAWS`` of them) come from their own seeded stream, column by column, so that every
# candidate's first sources get the same normals whatever its number of groups
SCATTER_SEED = 15
# the plan's own inflation estimate's draws (``NoiseScatter.with_estimate``): a stream apart from the run's sources
ESTIMATE_SEED = 18


def kernel_factor(bandwidth: int) -> float:
    """K = Σ_{|l| ≤ L} k(l)² of the Bartlett kernel k(l) = 1 − |l|/(L+1): the kernel estimate's variance over a
    plain mean square's, per effective sample."""
    return 1.0 + 2.0 * sum((1.0 - lag / (bandwidth + 1.0)) ** 2 for lag in range(1, bandwidth + 1))


def windows(samples: int, both: bool, joints: int, inflation: float) -> tuple[int, ...]:
    """The lag windows the run's rule (``wls.autocorrelation_time``) picks for a sweep of ``samples`` instants, one
    per replica of white noise through the run's angle matching (``noise_replicas``), × the plan's inflation² for
    noise correlated in time."""
    cap = max(1, int(wls.HAC_MAX_FRACTION * samples))
    scale = max(float(inflation), 1.0) ** 2
    return tuple(min(cap, max(1, math.ceil(w * scale))) for w in noise_replicas.replay(samples, both, joints).windows)


@dataclass(frozen=True)
class NoiseScatter:
    """The relative deviation of the run's noise variance from the plan's, per draw: (draws, 2) for the mass and
    the centre of mass (largest axis). ``relative_std``: their standard deviations (of the variance).

    ``estimate``: the factor, per draw, by which the plan's own noise term is off because its inflation is itself
    measured (the stored calibration run's robust-to-white ratio, one run's estimate: ``with_estimate``); shared by
    the mass and the CoM and by every repetition of the procedure, so ``over`` leaves it as it is. 1: none."""

    deviation: np.ndarray = dataclasses.field(compare=False, repr=False)
    relative_std: tuple[float, float] = (0.0, 0.0)
    estimate: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)  # (draws,)
    # the run's mean noise variance over its noise map's, mass and CoM: Σ_s share_s·E[max(ratio_s, 1)] over its
    # sweeps (the kernel ratio kept only above 1 raises the mean; more on short sweeps, whose ratio scatters more)
    kept: tuple[float, float] = (1.0, 1.0)

    def factors(self) -> np.ndarray:
        """The run's noise variance over the plan's, per draw (never below 0)."""
        own = np.maximum(1.0 + self.deviation, 0.0)
        return own if self.estimate is None else own * self.estimate[:, None]

    def over(self, runs: int) -> "NoiseScatter":
        """The same for ``runs`` repetitions averaged (each run's estimate is independent; the plan's is not)."""
        s = 1.0 / math.sqrt(runs)
        return NoiseScatter(self.deviation * s, (self.relative_std[0] * s, self.relative_std[1] * s), self.estimate,
                            self.kept)

    def with_estimate(self, ratio_rel_std: float) -> "NoiseScatter":
        """The same, with the plan's inflation known only to ``ratio_rel_std`` (relative standard deviation of the
        σ ratio): per draw the true ratio is the plan's × (1 + ratio_rel_std·z), z standard normal from a stream
        of its own (``ESTIMATE_SEED``: the same for every candidate), so the noise variance × its square."""
        if ratio_rel_std <= 0.0:
            return dataclasses.replace(self, estimate=None)
        z = np.random.default_rng(ESTIMATE_SEED).standard_normal(len(self.deviation))
        return dataclasses.replace(self, estimate=np.maximum(1.0 + ratio_rel_std * z, 0.0) ** 2)


def none(draws: int) -> NoiseScatter:
    return NoiseScatter(np.zeros((draws, 2)))


def _normals(draws: int, columns: int) -> np.ndarray:
    rng = np.random.default_rng(SCATTER_SEED)
    return np.column_stack([rng.standard_normal(draws) for _ in range(columns)]) if columns else np.zeros((draws, 0))


def kernel_ratio(info: np.ndarray, inv: np.ndarray, bandwidth: int, shares: np.ndarray | None = None
                 ) -> tuple[float, float]:
    """(mean, standard deviation) of one sweep's kernel ratio (``wls.modelled_excess``: the mean over the parameters
    of the lag-window estimate of the scores' long-run variance over the noise's) on white noise.

    ``info``: (instants, p, p) each instant's Σ w·yyᵀ over the joints' rows (its scores' covariance at unit σ).
    The scores are of residuals, which the fit made orthogonal to every row's regressor: the lags of the window
    pick up that negative correlation, −Σ_{t,t'} k(t − t')·info_t[k]·(YᵀWY)⁻¹·info_t'[k] for parameter k (the fit's
    leverage, which a short sweep feels most: the mean ratio of j2_pair 12 %, 0–15° on the UR5e came out 0.95).
    The lags beyond 0 also carry the scatter, 2·Σ_{l≥1} k(l)²·Σ_t info_t[k, l']²/(V_k·V_l') between two parameters'
    ratios (Gaussian scores whose covariance changes slowly along the sweep), averaged over the p × p pairs. Lag 0
    scatters too, less what the joints' own σ̂² (the denominator) share with it: 2·(Σ_t info_t[k, l]²/(V_k·V_l) −
    Σ_j s_jk·s_jl/m) with ``shares`` s_jk joint j's part of V_k ((joints, p); None: lag 0 left out, as before
    session 19). It vanishes for scores that weigh every instant alike and is what the run's ratio scattered beyond
    the lags (60 seeds of sim-ec66, j2_triple 7 %, at fixed windows 4–12: 4–14 % above the lags' alone)."""
    p = info.shape[1]
    kern = info.copy()
    for lag in range(1, bandwidth + 1):
        k = 1.0 - lag / (bandwidth + 1.0)
        kern[lag:] += k * info[:-lag]
        kern[:-lag] += k * info[lag:]
    V = np.maximum(np.einsum("tkk->k", info), 1e-300)
    leverage = np.einsum("tka,ab,tkb->k", info, inv, kern)
    centre = float(np.mean(1.0 - leverage / V))
    pairs = np.einsum("tkl->kl", info ** 2) / np.outer(V, V)
    var = 2.0 * (kernel_factor(bandwidth) - 1.0) * float(np.sum(pairs)) / p ** 2
    if shares is not None:
        var += 2.0 * float(np.sum(pairs - shares.T @ shares / len(info))) / p ** 2
    return centre, math.sqrt(max(var, 0.0))


def scatter(groups: Sequence[wls.Group], w: np.ndarray, inv: np.ndarray, directions: np.ndarray, inflation: float,
            draws: int, *, kernel_only: bool = False, both: dict[str, bool] | None = None) -> NoiseScatter:
    """The scatter of the run's noise variance of the quantities a·θ (``directions``: (2, p) rows a for the mass
    and the CoM's largest axis) for the planned rows ``groups`` with white weights ``w`` and (YᵀWY)⁻¹ ``inv``.

    ``kernel_only``: the sweeps' kernel ratios alone, without the groups' residual variances, i.e. the scatter of
    the fit's robust-to-white σ ratio (both σ scale with the same residual variances): how far one run's measured
    ratio (``noise_inflation``) is from the arm's."""
    groups = list(groups)
    both = both or {}  # per sweep: combined from two legs (default) or one leg
    joints = {name: sum(g.sweep == name for g in groups) for name in dict.fromkeys(g.sweep for g in groups)}
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    p = inv.shape[0]
    sweeps = list(dict.fromkeys(g.sweep for g in groups))
    n_src = len(groups) + len(sweeps)
    loads = np.zeros((n_src, len(directions)))  # per quantity: a group's share × its relative std, a sweep's share
    positive = np.zeros(n_src, bool)  # the sweeps' ratios: kept only above 1
    contrib = {}  # (group index) -> (rows, p + q) per-row variance contributions for the unit and quantity directions
    unit = np.vstack([np.eye(p), directions])
    totals = np.einsum("ij,jk,ik->i", unit, inv, unit)
    for i, g in enumerate(groups):
        ww = w[starts[i]:starts[i + 1]]
        contrib[i] = (g.Y @ inv @ unit.T) ** 2 * ww[:, None]
        share = contrib[i][:, p:].sum(axis=0) / np.maximum(totals[p:], 1e-300)
        f = noise_replicas.replay(len(g.y), both.get(g.sweep, True), joints[g.sweep]).dof_factor
        loads[i] = 0.0 if kernel_only else share * math.sqrt(2.0 * f / max(len(g.y), 1))
    ratios = []  # per sweep: (expected kernel ratio, its standard deviation) over the windows the run may pick
    for s, name in enumerate(sweeps):
        members = [i for i, g in enumerate(groups) if g.sweep == name]
        m = len(groups[members[0]].y)
        per = [np.einsum("t,tk,tl->tkl", w[starts[i]:starts[i + 1]], groups[i].Y, groups[i].Y) for i in members]
        info = sum(per)
        V = np.maximum(np.einsum("tkk->k", info), 1e-300)
        shares = np.array([np.einsum("tkk->k", x) for x in per]) / V
        picked = windows(m, both.get(name, True), len(members), inflation)
        each = {L: kernel_ratio(info, inv, L, shares) for L in set(picked)}
        centres = np.array([each[L][0] for L in picked])
        spread = np.array([each[L][1] for L in picked])
        ratios.append((float(np.mean(centres)), math.sqrt(float(np.mean(spread ** 2) + np.var(centres)))))
        share = sum(contrib[i][:, p:].sum(axis=0) for i in members) / np.maximum(totals[p:], 1e-300)
        loads[len(groups) + s] = share
        positive[len(groups) + s] = True
    z = _normals(draws, n_src)
    means = np.ones(n_src)
    # the run keeps max(ratio, 1) of a ratio centred at the inflation² (the draws are relative to it): centred draws
    floor = 1.0 / max(float(inflation), 1.0) ** 2
    for col, (centre, std) in zip(np.flatnonzero(positive), ratios):
        kept = np.maximum(centre + std * z[:, col], floor)
        means[col] = np.mean(kept)
        z[:, col] = kept - means[col]
    deviation = z @ loads
    kept = (means[positive] @ loads[positive]) / np.maximum(loads[positive].sum(axis=0), 1e-300)
    return NoiseScatter(deviation, tuple(float(v) for v in np.std(deviation, axis=0)), kept=tuple(float(k) for k in kept))


__all__ = ["ESTIMATE_SEED", "kernel_factor", "windows", "NoiseScatter", "none", "kernel_ratio", "scatter"]
