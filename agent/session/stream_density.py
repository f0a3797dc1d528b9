"""The sample density a run of this robot will have: what its stored runs delivered, against the nominal rate.

``plan --target-std`` places each planned sweep's constant-speed samples at one period, and its white-noise
term scales with that period (σ² per second of sweep = σ²_sample / rate). A controller that streams without
gaps delivers its nominal rate; a stream that drops samples (a simulation on a busy host, a congested
network, a slow serial line) delivers fewer, and the run then carries that much less information. The stored
runs of the robot, the empty-flange baseline and the drive-gain calibration's run (both phases), say what its
stream delivers: per complete sweep, the samples per second of robot time in the manifest's stream statistics
(``types.StreamStats``). Their harmonic mean over the sweeps is what the prediction assumes: a run's variance
goes as 1/rate, so the mean of 1/rate is its expectation. Without a stored run: the nominal rate, said so.

Everything is in robot time (the time the sweeps' speeds are in): the controller clock's rate where the stream
stamps samples, else the receive rate (a real robot: robot time is wall time). Where the agent's own clock
paces the samples (CANopen SYNC), a simulation running ``time_scale`` times faster than the wall clock gets
1/``time_scale`` of the SYNC rate per simulated second, and that is its nominal rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

from payload_agent.configuration.config import Config

MIN_SWEEP_COUNT = 10  # a sweep with fewer samples says nothing about the rate (aborted, or a stub)
DENSE_SHARE = 0.95  # a stream keeping this share of its samples is reported as dense


@dataclass(frozen=True)
class StreamDensity:
    """The period the plan places samples at, and where it came from."""

    period_s: float  # robot seconds between the samples a run keeps (what the prediction assumes)
    nominal_period_s: float  # the stream's nominal period in robot seconds
    kept_share: float  # delivered / nominal samples (harmonic mean over the stored sweeps); 1 without any
    sweeps: int  # stored sweeps measured (0: no stored run, nominal assumed)
    runs: tuple[str, ...] = ()  # the stored runs' folders measured

    def describe(self) -> str:
        nominal = f"{1.0 / self.nominal_period_s:.0f}"
        if not self.sweeps:
            return f"sample rate: the nominal {nominal} per s (no stored run to measure it in)"
        what = (f"{1.0 / self.period_s:.0f} of the nominal {nominal} samples per s of sweep "
                f"({100 * self.kept_share:.0f} %)")
        where = f"in {self.sweeps} sweeps of the stored runs ({', '.join(self.runs)})"
        if self.kept_share >= DENSE_SHARE:
            return f"sample rate: {what} {where}: dense, as predicted for the run"
        return f"sample rate: {what} {where}: the stream drops samples, and the prediction assumes the same"


def nominal_period_s(config: Config, driver: Any) -> float:
    """The stream's nominal period in robot seconds: the driver's, times ``time_scale`` in a simulation whose
    samples the agent's clock paces (fewer per simulated second)."""
    period = float(driver.nominal_period_s)
    sim = config.simulation
    if sim is not None and getattr(driver, "sampling_clock", "controller") == "agent":
        period *= float(sim.time_scale)
    return period


def sweep_rate_hz(entry: Mapping[str, Any], time_scale: float = 1.0) -> float | None:
    """Samples per robot second of one recorded sweep (its manifest entry), or None when it cannot tell: the
    controller clock's rate where the stream has one, else the receive rate in real time. A time-scaled
    simulation's receive rate says nothing without its clock (its samples arrive in bursts), nor does a manifest
    written before ``controller_rate_hz`` was recorded."""
    stream = entry.get("stream") or {}
    if entry.get("status") != "complete" or int(stream.get("count") or 0) < MIN_SWEEP_COUNT:
        return None
    ctrl = stream.get("controller_rate_hz")
    if ctrl:
        return float(ctrl)
    wall = stream.get("achieved_rate_hz")
    return float(wall) if wall and time_scale == 1.0 else None


def stored_runs(config: Config) -> list[Path]:
    """The robot's stored runs whose streams are measured: the baseline's folder and the calibration's run."""
    from payload_agent.evaluation.calibration import effective_calibration
    from payload_agent.recording.state import RobotState

    folders = []
    baseline = RobotState.for_config(config).baseline_dir
    if (baseline / "manifest.json").is_file():
        folders.append(baseline)
    cal = effective_calibration(config)
    if cal is not None and (Path(cal.run_dir) / "manifest.json").is_file():
        folders.append(Path(cal.run_dir))
    return folders


def delivered(config: Config, nominal_s: float, folders: Iterable[Path] | None = None) -> StreamDensity:
    """What the stored runs' sweeps delivered against ``nominal_s`` (robot seconds), as the plan assumes it."""
    from payload_agent.errors import DataError
    from payload_agent.recording.rundata import load_manifest

    scale = float(config.simulation.time_scale) if config.simulation is not None else 1.0
    inverse, names = [], []
    for folder in (stored_runs(config) if folders is None else folders):
        try:
            manifest = load_manifest(folder)
        except DataError:
            continue
        shares = [min(rate * nominal_s, 1.0)
                  for phase in (manifest.get("phases") or {}).values()
                  for entry in (phase or {}).get("sweeps", [])
                  if (rate := sweep_rate_hz(entry, scale)) is not None and rate > 0]
        if shares:
            inverse += [1.0 / s for s in shares]
            names.append(Path(folder).name)
    if not inverse:
        return StreamDensity(nominal_s, nominal_s, 1.0, 0)
    share = len(inverse) / math.fsum(inverse)
    return StreamDensity(nominal_s / share, nominal_s, share, len(inverse), tuple(names))
