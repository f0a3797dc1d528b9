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
subtraction's full variance that the plan assumes. On white noise and a whole stream the fit shows
``WHITE_RATIO`` (measured: 20 sim-ur5e runs with whole streams 1.12–1.44, mean 1.24, their calibration runs
1.23–1.27, an EC66 run 1.21–1.22; 30 seeds of white noise on the EC66's sweeps 1.26,
``tests/test_noise_inflation.py``), and the plan takes the stored run's
ratio over it. What remains is the noise's correlation in time and the holes of a stream that drops
samples (a simulated UR read through ur_rtde's polled receive interface showed 2.0–2.5, docs/benchmarks.md
session 14).

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
WHITE_RATIO = 1.22  # the fit's robust-to-white ratio on white noise and a whole stream (module docstring)


@dataclass(frozen=True)
class NoiseInflation:
    """The robust-to-white σ ratio the plan assumes, and where it came from."""

    ratio: float  # what ``NoiseModel.inflation`` gets: the larger of the two over WHITE_RATIO (1: none measured)
    mass_ratio: float | None = None  # robust / white σ of the mass in the stored run
    cog_ratio: float | None = None  # robust / white σ of the centre of mass (its largest axis)
    run: str = ""  # the stored run's folder name
    why_none: str = "no stored calibration run to measure its correlation in"  # when nothing was measured

    def describe(self) -> str:
        if self.mass_ratio is None:
            return f"noise taken as white ({self.why_none})"
        return (f"noise term × {self.ratio:.2f} for the noise's correlation, as the stored run {self.run} showed (its "
                f"robust σ {self.mass_ratio:.2f} × the white one for the mass, {self.cog_ratio:.2f} for the centre of "
                f"mass, over the {WHITE_RATIO:g} of white noise)")


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
    from payload_agent.evaluation import systematics
    from payload_agent.solvers import general

    prepared = systematics.prepare(loaded, empty, config.robot.joints, commands)
    fit = general.fit_model(prepared.deltas, config.robot.kinematics).fit()
    return ratios(fit.cov, fit.cov_iid, fit.theta)


def of_run(config: Config, run_dir: Path) -> NoiseInflation:
    """The robust-to-white ratio of a recorded run with a loaded and an empty phase (DataError if it has none)."""
    from payload_agent.analysis.run_deltas import phases_for

    loaded, empty, commands = phases_for(Path(run_dir), np.asarray(config.effort.gains_nm_per_unit, float))
    mass, cog = of_sweeps(config, loaded, empty, commands)
    return NoiseInflation(max(MIN_RATIO, max(mass, cog) / WHITE_RATIO), mass, cog, Path(run_dir).name)


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
