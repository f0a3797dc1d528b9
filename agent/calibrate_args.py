"""`payload-agent calibrate`'s command-line values, checked: the reference payload, the sweep-speed override and
the procedure override.

A calibration is run once per robot and every later run carries its drive-gain uncertainty, so a slower
calibration than the YAML's identification speed can pay (``--speed-percent``; docs/benchmarks.md, issue 22:
on sim-ec66 a 5 kg reference off the flange axis at 5 % cut the gains' share of a 2 kg tool's mass σ from 0.78
to 0.28 g). The override changes the sweep speed only; the safety gate checks the plan as for every run.

A calibration absorbs into its gains and zeros part of the arm's DH-length errors, and which part depends on where
its sweeps lie: a calibration that swept the procedure the tool runs will sweep absorbs nearly all of it (the
reference's lever changes as the tool's does), one on another procedure does not (docs/benchmarks.md, "Session 15:
the length term after a calibration on another procedure"). ``--procedure`` lets the user calibrate on the
procedure ``plan --target-std`` chose; it changes which poses and sweeps are recorded (the inertia part is left
out: the calibration does not use it), and the safety gate checks that plan whole as for every run.
"""

from __future__ import annotations

import dataclasses
import math

from pathlib import Path

from payload_agent.configuration.config import Config
from payload_agent.configuration.procedure import load_procedure
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


def with_procedure(config: Config, name_or_file: str | None) -> Config:
    """The config with ``--procedure`` (a bundled procedure's name or a procedure file) as the procedure whose poses
    and sweeps the calibration records (unchanged without one); the file is read and checked as the YAML's
    ``procedure.name`` is, and a file's path is kept absolute (the calibration records it)."""
    if name_or_file is None:
        return config
    path = Path(name_or_file).expanduser()
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise ConfigError("--procedure", f"no procedure file {str(path)!r} (give a bundled procedure's name or "
                                             "the path of a procedure YAML file)")
        name_or_file = str(path.resolve())
    try:
        load_procedure(name_or_file)
    except ConfigError as exc:  # the file's own key path stays in the message: it says what to fix in the file
        where = "" if exc.source is None else f"{exc.source}: {exc.key_path}: "
        raise ConfigError("--procedure", where + exc.problem) from None
    # the calibration fits its gains and zeros on the sweeps alone: the inertia part's wrist moves would add robot
    # time and nothing to it, and after the empty run they can end a whole turn from another procedure's first pose
    # (j2_quarter on sim-ur5e: a 270° approach of joint 6 that the safety gate refuses before the loaded run)
    return dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, name=name_or_file,
                                                                     inertia=None))


def with_sweep_and_motion(config: Config, sweep_deg: str | None = None, travel_percent: float | None = None,
                          accel_percent: float | None = None) -> Config:
    """The config with ``--sweep-deg FROM,TO``, ``--travel-speed-percent`` and ``--accel-percent`` as the procedure's
    (each unchanged without one), checked as the YAML's keys are. With ``--procedure`` and ``--speed-percent`` they
    make the calibration's plan any candidate's of ``plan --target-std``: a run of that plan then reuses the empty run
    the calibration recorded and shares its noise (``session.stored_candidate``; docs/benchmarks.md, session 20)."""
    pc, cap = config.procedure, config.safety.max_speed_percent
    changes: dict = {}
    if sweep_deg is not None:
        try:
            lo, hi = (float(v) for v in sweep_deg.split(","))
        except ValueError:
            lo = hi = math.nan
        if not (-90 <= lo <= 90 and -90 <= hi <= 90 and hi - lo >= 10):
            raise ConfigError("--sweep-deg", f"expected FROM,TO in degrees of link elevation within -90 to 90 and at "
                                             f"least 10 apart (as procedure.sweep_deg), got {sweep_deg!r}")
        changes.update(sweep_from_deg=lo, sweep_to_deg=hi)
    for option, key, value, top in (("--travel-speed-percent", "travel_speed_percent", travel_percent, cap),
                                    ("--accel-percent", "accel_percent", accel_percent, 100.0)):
        if value is None:
            continue
        if not (math.isfinite(value) and 0 < value <= top):
            raise ConfigError(option, f"expected a percentage above 0 and at most {top:g} % "
                                      + (f"(safety.max_speed_percent in {config.source})" if top == cap else "")
                                      + f", got {value:g}")
        changes[key] = float(value)
    return dataclasses.replace(config, procedure=dataclasses.replace(pc, **changes)) if changes else config
