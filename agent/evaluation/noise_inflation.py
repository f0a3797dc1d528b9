"""How much wider than white noise a stored run's statistical σ came out: the plan's ``NoiseModel.inflation``.

A run reports the autocorrelation-robust σ of its fit (``solvers.wls.fit``: the sandwich over each sweep's
lags), never below the textbook σ for independent noise. ``plan --target-std`` predicts the white-noise σ
at the sample density the stored runs delivered (``session.stream_density``). Where the noise is correlated
in time (a drive's ripple, a stream whose gaps leave runs of samples), the robust σ is wider, by a ratio
that a run of the same arm and stream shows: the stored run that has a loaded phase, the drive-gain
calibration's. Its fit is made again here on its recorded sweeps (nominal gains: the ratio does not depend
on their scale) and the ratio of robust to white σ of the mass and of the centre of mass is read off.

Part of that ratio is in the plan's white term already: the run matches the empty run's samples to the
loaded run's by angle, which correlates neighbouring deltas, and the fit's independent-rows σ understates the
subtraction's full variance that the plan assumes. How much depends on where the two runs' samples fall against
each other, which is chance: on sim-ec66's calibration (paper_bd 5 %) the run's ratio on white noise scattered
from 1.11 to 1.25 between seeds (docs/benchmarks.md "Session 18"). So the white part is not a constant: it is
computed for the stored run's own rows, the fit's covariance from each sweep's noise map alone
(``wls.modelled_noise``, what white noise would give), and the plan takes the reported ratio over it. What remains
is the noise's correlation in time. A stream with holes (a simulated UR read through ur_rtde's polled receive
interface showed 2.0–2.5, docs/benchmarks.md session 14) keeps ``WHITE_RATIO`` as the white part: the map holds the
holes' correlation too, which the plan's white term does not. Over ``WHITE_RATIO`` instead, the plan's noise term followed each calibration's chance (12 seeds:
ratio 1.23 ± 0.05, over its own map 1.02 ± 0.016), and every run it predicted carried that error.

What is left is one run's estimate of the kernel excess (``noise_scatter``: its kernel ratios' scatter, about
1 %): ``NoiseInflation.rel_std`` sizes it from the stored run's own rows (``noise_scatter.scatter(kernel_only=
True)``) and the plan draws it (``noise_scatter.NoiseScatter.with_estimate``).

An empty-flange baseline has no loaded phase and says nothing about it; without a calibration run the ratio
is 1 (said so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from payload_agent.configuration.config import Config

MIN_RATIO = 1.0  # the run's robust σ is never below its white one (``wls.fit``)
# the fit's robust-to-white ratio on white noise and a whole stream, on average (measured: 20 sim-ur5e runs with whole
# streams 1.12–1.44, mean 1.24; 30 seeds of white noise on the EC66's sweeps 1.26): where a sweep has no noise map
WHITE_RATIO = 1.22


@dataclass(frozen=True)
class NoiseInflation:
    """The robust-to-white σ ratio the plan assumes, and where it came from."""

    # what ``NoiseModel.inflation`` gets: the larger of the two over what white noise shows on the same rows (the
    # run's own noise map, ``Measured.excess``; 1: none measured)
    ratio: float
    mass_ratio: float | None = None  # robust / white σ of the mass in the stored run
    cog_ratio: float | None = None  # robust / white σ of the centre of mass (its largest axis)
    run: str = ""  # the stored run's folder name
    why_none: str = "no stored calibration run to measure its correlation in"  # when nothing was measured
    rel_std: float = 0.0  # relative standard deviation of ``ratio`` as one run's estimate (0: none measured)
    # what white noise shows on the stored run's rows (its noise map alone), mass and CoM: ``ratio``'s reference
    white_ratios: tuple[float, float] = (WHITE_RATIO, WHITE_RATIO)
    kept: float = 1.0  # ``Measured.kept``: what white noise's kept kernel ratios give the stored run beyond its map

    def describe(self) -> str:
        if self.mass_ratio is None:
            return f"noise taken as white ({self.why_none})"
        return (f"noise term × {self.ratio:.2f} for the noise's correlation, as the stored run {self.run} showed (its "
                f"robust σ {self.mass_ratio:.2f} × the white one for the mass, {self.cog_ratio:.2f} for the centre of "
                f"mass, over the {self.white_ratios[0]:.2f} and {self.white_ratios[1]:.2f} that white noise shows on "
                f"its rows; known to ±{100 * self.rel_std:.1f} %)")


def ratios(cov: np.ndarray, cov_iid: np.ndarray, theta: np.ndarray) -> tuple[float, float]:
    """(mass, largest CoM axis) robust-to-white σ ratios of a fit of θ = [m, m·cx, m·cy, m·cz]."""
    m = float(theta[0])
    J = np.zeros((3, 4))  # c = (m·c) / m
    J[:, 0] = -np.asarray(theta[1:], float) / m ** 2
    J[:, 1:] = np.eye(3) / m
    com = np.sqrt(np.maximum(np.diag(J @ cov @ J.T), 0.0))
    com_iid = np.sqrt(np.maximum(np.diag(J @ cov_iid @ J.T), 1e-300))
    axis = int(np.argmax(com))
    mass = math.sqrt(max(cov[0, 0], 0.0) / max(cov_iid[0, 0], 1e-300))
    return mass, float(com[axis] / com_iid[axis])


def of_sweeps(config: Config, loaded, empty, commands=None) -> tuple[float, float]:
    """(mass, CoM) robust-to-white σ ratios of the fit the run makes of these sweeps (effort in N·m)."""
    m = measure(config, loaded, empty, commands)
    return m.mass_ratio, m.cog_ratio


SCATTER_DRAWS = 4000  # draws of ``noise_scatter.scatter`` for the estimate's own scatter


@dataclass(frozen=True)
class Measured:
    """What one run's fit shows of its noise: robust-to-white σ ratios as reported and as its noise map alone
    gives them (the same rows with white noise) and the excess's scatter as an estimate."""

    mass_ratio: float
    cog_ratio: float
    map_mass_ratio: float  # what white noise shows on these rows: the angle matching's correlation alone
    map_cog_ratio: float
    rel_std: float  # relative standard deviation of ``excess`` as one run's estimate (its kernel ratios' scatter)
    # the σ ratio the run's kernel ratios, kept only above 1, give it beyond its map on average (√``NoiseScatter.kept``;
    # also over ``WHITE_RATIO``, an average with its own: the plan multiplies each candidate's own back in)
    kept: float = 1.0

    @property
    def excess(self) -> float:
        """How much wider than white noise the run's noise was: the reported ratio over the map's (never < 1), over
        what white noise gives on these rows on average (``kept``): the plan adds each candidate's own."""
        return max(MIN_RATIO, self.mass_ratio / self.map_mass_ratio, self.cog_ratio / self.map_cog_ratio) / self.kept


def _map_covariance(model, fit) -> np.ndarray | None:
    """The fit's covariance had its sweeps' noise been white: each sweep's score variance from its noise map alone
    (``wls.modelled_noise`` at every lag, the groups' noise variances as the fit took them), without the kernel
    excess ``wls.fit`` adds where the residuals show more. None when a sweep has no map."""
    from payload_agent.solvers import wls

    groups = list(model.groups)
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    B = np.zeros((len(fit.theta),) * 2)
    for sweep in dict.fromkeys(g.sweep for g in groups):
        members = [i for i, g in enumerate(groups) if g.sweep == sweep]
        noise = groups[members[0]].noise_map
        if noise is None or noise.shape[0] != len(groups[members[0]].y):
            return None
        B += wls.modelled_noise(noise @ noise.T, None, [
            (groups[i].Y * fit.weights[starts[i]:starts[i + 1], None], fit.noise_sigma_nm[groups[i].label] ** 2)
            for i in members])
    inv = fit.normal_inverse
    return inv @ B @ inv


GAP_FACTOR = 1.5  # a step between two samples this many times the sweep's median step: a hole in the stream


def whole_stream(*runs) -> bool:
    """Whether every sweep of these runs came without a hole (no step between samples over ``GAP_FACTOR`` × the
    median): then the noise map holds only the angle matching's correlation, which the plan's white term does not
    model per run; holes stay in the inflation (the plan's white term assumes a whole stream)."""
    for sweeps in runs:
        for s in sweeps.values():
            dt = np.diff(np.asarray(s.t, float))
            if len(dt) and float(np.max(dt)) > GAP_FACTOR * float(np.median(dt)):
                return False
    return True


def measure(config: Config, loaded, empty, commands=None) -> Measured:
    """The fit the run makes of these sweeps (effort in N·m): its robust-to-white ratios, the same from its noise map
    alone (``WHITE_RATIO`` where a sweep has none or the stream a hole: ``whole_stream``), the excess's scatter as an estimate (``noise_scatter``'s kernel
    ratios on these rows in the direction of the larger)."""
    from payload_agent.evaluation import noise_scatter, systematics
    from payload_agent.solvers import general

    prepared = systematics.prepare(loaded, empty, config.robot.joints, commands)
    model = general.fit_model(prepared.deltas, config.robot.kinematics)
    fit = model.fit()
    mass, cog = ratios(fit.cov, fit.cov_iid, fit.theta)
    cov_map = _map_covariance(model, fit) if whole_stream(loaded, empty) else None
    map_mass, map_cog = (WHITE_RATIO, WHITE_RATIO) if cov_map is None else ratios(cov_map, fit.cov_iid, fit.theta)
    theta = np.asarray(fit.theta, float)
    J = np.zeros((3, len(theta)))  # the CoM's largest axis, as ``ratios`` reads it
    J[:, 0], J[:, 1:4] = -theta[1:4] / theta[0] ** 2, np.eye(3) / theta[0]
    axis = int(np.argmax(np.diag(J @ fit.cov @ J.T)))
    directions = np.vstack([np.eye(len(theta))[0], J[axis]])
    excess = max(MIN_RATIO, mass / map_mass, cog / map_cog)  # the scatter's window scale (as before)
    spread = noise_scatter.scatter(list(model.groups), fit.weights, fit.normal_inverse, directions, excess,
                                   SCATTER_DRAWS, kernel_only=True,
                                   both={k.name: k.direction == "both" for k in model.deltas})
    var_rel = spread.relative_std[0] if mass / map_mass >= cog / map_cog else spread.relative_std[1]
    # a variance's relative scatter is twice its root's
    kept = math.sqrt(spread.kept[0] if mass / map_mass >= cog / map_cog else spread.kept[1])
    return Measured(mass, cog, map_mass, map_cog, 0.5 * var_rel, kept)


def of_run(config: Config, run_dir: Path) -> NoiseInflation:
    """The robust-to-white ratio of a recorded run with a loaded and an empty phase (DataError if it has none)."""
    from payload_agent.analysis.run_deltas import phases_for

    loaded, empty, commands = phases_for(Path(run_dir), np.asarray(config.effort.gains_nm_per_unit, float))
    m = measure(config, loaded, empty, commands)
    return NoiseInflation(m.excess, m.mass_ratio, m.cog_ratio, Path(run_dir).name, rel_std=m.rel_std,
                          white_ratios=(m.map_mass_ratio, m.map_cog_ratio), kept=m.kept)


def stored(config: Config) -> NoiseInflation:
    """The ratio of the robot's stored calibration run, or 1 without one (or when it cannot be fitted)."""
    from payload_agent.errors import DataError
    from payload_agent.evaluation.calibration import effective_calibration

    cal = effective_calibration(config)
    if cal is None:
        return NoiseInflation(MIN_RATIO)
    if not (Path(cal.run_dir) / "manifest.json").is_file():
        return NoiseInflation(MIN_RATIO, why_none=f"the calibration's run folder {cal.run_dir} is gone")
    try:
        return of_run(config, Path(cal.run_dir))
    except DataError as exc:  # e.g. a calibration whose empty phase was a stored baseline's
        return NoiseInflation(MIN_RATIO, why_none=f"the calibration run {Path(cal.run_dir).name} cannot be fitted "
                                                  f"again: {exc}")
