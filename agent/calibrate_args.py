"""`payload-agent calibrate`'s command-line values, checked: the reference payload and the sweep-speed override.

A calibration is run once per robot and every later run carries its drive-gain uncertainty, so a slower
calibration than the YAML's identification speed can pay (``--speed-percent``; docs/benchmarks.md, issue 22:
on sim-ec66 a 5 kg reference off the flange axis at 5 % cut the gains' share of a 2 kg tool's mass σ from 0.78
to 0.28 g). The override changes the sweep speed only; the safety gate checks the plan as for every run.
"""

from __future__ import annotations

import dataclasses
import math

from payload_agent.configuration.config import Config
from payload_agent.errors import ConfigError
from payload_agent.types import PayloadSetting


def reference_payload(known_mass_kg: float, known_cog: str) -> tuple[PayloadSetting, tuple[float, float, float]]:
    """``--known-mass``/``--known-cog`` as the reference payload (SI) and its centre of mass in mm."""
    try:
        cog = tuple(float(v) for v in known_cog.split(","))
        if len(cog) != 3 or not all(math.isfinite(c) for c in cog):
            raise ValueError
    except ValueError:
        raise ConfigError("--known-cog", f"expected three numbers in mm separated by commas, got {known_cog!r}")
    if not 0 < known_mass_kg < 100:
        raise ConfigError("--known-mass", f"expected the reference payload's mass in kg, got {known_mass_kg:g}")
    return PayloadSetting(mass_kg=known_mass_kg, cog_m=tuple(v / 1000.0 for v in cog)), cog


def with_speed(config: Config, speed_percent: float | None) -> Config:
    """The config with ``--speed-percent`` as the procedure's sweep speed (unchanged without one)."""
    if speed_percent is None:
        return config
    cap = config.safety.max_speed_percent
    if not (math.isfinite(speed_percent) and 0 < speed_percent <= cap):
        raise ConfigError("--speed-percent", f"expected a sweep speed above 0 and at most the robot's cap of {cap:g} % "
                                             f"(safety.max_speed_percent in {config.source}), got {speed_percent:g}")
    return dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, speed_percent=speed_percent))
