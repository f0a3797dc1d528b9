"""`plan --target-std G,MM`: predict each candidate procedure's σ before moving and pick the fastest that meets it.

The effort noise comes from the stored empty-flange baseline when there is one (measured in its
constant-speed windows), else from the simulation's declared noise; a real robot without a
baseline is refused with what to do. The prediction itself is ``evaluation.design``.
"""

from __future__ import annotations

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.errors import ConfigError, DataError
from payload_agent.evaluation.design import Choice, NoiseModel, choose, measured_effort_std
from payload_agent.recording.state import RobotState
from payload_agent.session.connection import build_driver


def parse_target(text: str) -> tuple[float, float]:
    try:
        grams, mm = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError("--target-std", f"expected G_GRAMS,MM (for example 2,1), got {text!r}") from None
    if not (grams > 0 and mm > 0):
        raise ConfigError("--target-std", f"both targets must be positive, got {text!r}")
    return grams, mm


def noise_for(config: Config) -> tuple[NoiseModel, str]:
    """The noise the prediction assumes, and where it came from."""
    period = build_driver(config).nominal_period_s
    state = RobotState.for_config(config)
    if (state.baseline_dir / "empty").is_dir():
        from payload_agent.recording.rundata import load_manifest, load_phase

        try:
            manifest = load_manifest(state.baseline_dir)
            gains = np.asarray(manifest.get("gains_nm_per_unit") or config.effort.gains_nm_per_unit, float)
            empty = load_phase(state.baseline_dir, "empty", gains, manifest)
            std = measured_effort_std(empty)
            return (NoiseModel(std, period, length_std_m=config.robot.length_uncertainty_m, joints=config.robot.joints,
                               friction_level_nm=baseline_friction_nm(empty)),
                    f"effort noise and friction measured in the stored baseline ({state.baseline_dir})")
        except DataError:
            pass
    if config.simulation is not None:
        return (NoiseModel(tuple(config.simulation.noise_nm), period, length_std_m=config.robot.length_uncertainty_m,
                           joints=config.robot.joints, friction_level_nm=tuple(config.simulation.coulomb_nm)),
                "effort noise and friction declared in the simulation section (no stored baseline)")
    raise ConfigError("--target-std", "no stored empty-flange baseline to measure the effort noise from: record one "
                                      "with `payload-agent baseline`, then plan for a target accuracy", config.source)


def baseline_friction_nm(empty) -> tuple[float, ...] | None:
    """Each joint's friction level in the baseline's sweeps (largest over its poses), for the
    residual-friction term of the prediction (``systematics.planned_covariance``)."""
    from payload_agent.evaluation.systematics.offsets import friction_gaps

    level = [0.0] * 6
    for (_, j), gap in friction_gaps(empty).items():
        level[j] = max(level[j], abs(float(gap.level_nm)))
    return tuple(level) if any(level) else None


def plan_for_target(config: Config, text: str) -> tuple[Choice, str]:
    grams, mm = parse_target(text)
    noise, source = noise_for(config)
    return choose(config, grams, mm, noise), source
