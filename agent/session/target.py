"""`plan --target-std G,MM`: predict each candidate procedure's σ before moving and pick the fastest that meets it.

The effort noise comes from the stored empty-flange baseline when there is one (measured in its
constant-speed windows), else from the simulation's declared noise; a real robot without a
baseline is refused with what to do. The samples per second of sweep are what the stored runs delivered
(``stream_density``), else the nominal rate; the noise's correlation in time widens the noise term by the
robust-to-white σ ratio the stored calibration run's own fit showed (``noise_inflation``), else not. The drive gains' uncertainty is the one the run will carry:
the stored calibration's (whose fit also absorbs most of the DH-length error), or none with nominal
gains, exactly as ``pipeline.run_gains`` gives the run. The candidates are the grid and the stored baseline's plan, whose
run reuses the stored empty run (``stored_candidate``). The payload the prediction assumes is the
user's (``--payload-kg``/``--payload-cog-mm`` or a tool library entry), else a nominal one, and the
output names it. The prediction itself is ``evaluation.design``.
"""

from __future__ import annotations

import numpy as np

from dataclasses import dataclass

from payload_agent.configuration.config import Config
from payload_agent.errors import ConfigError, DataError
from payload_agent.evaluation.design import Choice, NoiseModel, choose
from payload_agent.evaluation.planned_baseline import SharedBaseline
from payload_agent.evaluation.effort_noise import moving_and_standing_std
from payload_agent.recording import resting_pose
from payload_agent.recording.state import RobotState
from payload_agent.session import stream_density
from payload_agent.session.connection import build_driver


def parse_target(text: str) -> tuple[float, float]:
    try:
        grams, mm = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError("--target-std", f"expected G_GRAMS,MM (for example 2,1), got {text!r}") from None
    if not (grams > 0 and mm > 0):
        raise ConfigError("--target-std", f"both targets must be positive, got {text!r}")
    return grams, mm


NOMINAL_MASS_KG, NOMINAL_COG_MM = 2.0, (0.0, 0.0, 100.0)


@dataclass(frozen=True)
class ExpectedPayload:
    """The payload the prediction is made for (σ depends on it: the centre of mass's σ scales as 1/mass)."""

    mass_kg: float
    cog_mm: tuple[float, float, float]
    source: str  # "given", "tool library entry NAME", "nominal (not given)"

    def describe(self) -> str:
        x, y, z = self.cog_mm
        return f"{self.mass_kg:g} kg at {x:g}, {y:g}, {z:g} mm ({self.source})"


def expected_payload(config: Config, mass_kg: float | None = None, cog_mm: str | None = None,
                     tool: str | None = None) -> ExpectedPayload:
    """From ``--payload-kg``/``--payload-cog-mm``, or ``--tool NAME``'s library entry, else the nominal payload."""
    if tool and (mass_kg is not None or cog_mm):
        raise ConfigError("--tool", "give either --tool or --payload-kg/--payload-cog-mm, not both")
    if tool:
        from payload_agent.tools import library

        state = RobotState.for_config(config)
        entry = library.require(library.tool_library_path(state.root), config.robot.name, tool)
        return ExpectedPayload(float(entry.mass_kg), tuple(float(v) for v in entry.cog_mm),
                               f"tool library entry {tool!r}")
    if cog_mm is not None and mass_kg is None:
        raise ConfigError("--payload-cog-mm", "needs --payload-kg too (the mass the prediction assumes)")
    if mass_kg is None:
        return ExpectedPayload(NOMINAL_MASS_KG, NOMINAL_COG_MM, "nominal: give --payload-kg and --payload-cog-mm "
                                                                "or --tool NAME for yours")
    if not (0.0 < mass_kg < 1000.0):
        raise ConfigError("--payload-kg", f"expected a mass in kg above 0, got {mass_kg:g}")
    cog = NOMINAL_COG_MM
    if cog_mm is not None:
        try:
            cog = tuple(float(v) for v in cog_mm.split(","))
        except ValueError:
            cog = ()
        if len(cog) != 3 or not all(abs(v) < 5000.0 for v in cog):
            raise ConfigError("--payload-cog-mm", f"expected X,Y,Z in mm in the flange frame (for example 0,0,80), "
                                                  f"got {cog_mm!r}")
    return ExpectedPayload(float(mass_kg), cog, "given" if cog_mm is not None else
                           f"given mass, nominal centre of mass {NOMINAL_COG_MM[2]:g} mm on the flange axis")


def noise_for(config: Config) -> tuple[NoiseModel, str]:
    """The noise the prediction assumes, and where it came from; with the drive-gain uncertainty the run
    will carry (a stored calibration's, else none: nominal gains are reported without it)."""
    import dataclasses

    from payload_agent.evaluation.calibration import effective_calibration
    from payload_agent.evaluation.pipeline import run_gains

    from payload_agent.evaluation.planned_terms import earlier_friction_change

    noise, source = _effort_noise(config)
    from payload_agent.evaluation import noise_inflation

    inflation = noise_inflation.stored(config)  # the stored calibration run's robust-to-white σ ratio
    noise, source = (dataclasses.replace(noise, inflation=inflation.ratio, inflation_rel_std=inflation.rel_std),
                     source + "; " + inflation.describe())
    known = earlier_friction_change(config) if noise.friction_level_nm is not None else None
    if known is not None:
        noise, source = dataclasses.replace(noise, friction_known=known), source + "; " + known.source
    gains = run_gains(config, None)
    if gains.rel_std is not None and effective_calibration(config) is None:  # the controller's constants (a UR)
        return (dataclasses.replace(noise, gain_rel_std=gains.rel_std, gain_swept_only=True),
                source + f"; drive gains: {gains.source}, whose uncertainty a run carries for the joints it sweeps")
    if gains.rel_std is None:
        return noise, source + "; nominal drive gains (no calibration stored)"
    if gains.zeros is not None and noise.joints is not None:  # the run's zero term: the measured σ (zero_offsets)
        from payload_agent.evaluation.zero_offsets import declaration

        noise = dataclasses.replace(noise, joints=declaration(noise.joints, gains.zeros))
    zeros = "" if gains.zeros is None else " and the joint zeros it measured"
    swept = effective_calibration(config).procedure
    swept = "" if swept is None else f" (it swept {swept.describe()})"
    shared = shared_baseline(config)
    if shared is not None:
        swept += (f"; a run of its stored baseline's plan ({shared.procedure} {shared.speed_percent:g} %) subtracts the "
                  f"empty run the calibration did")
    return (dataclasses.replace(noise, gain_rel_std=gains.rel_std, gain_reference=gains.reference,
                                shared_baseline=shared),
            source + "; the stored drive-gain calibration's uncertainty" + zeros + swept)


def shared_baseline(config: Config) -> SharedBaseline | None:
    """The stored baseline when the stored calibration subtracted it (its empty run became it, or it reused it): a
    run of its plan subtracts it too, and ``Gains.shared_baseline`` holds for that run; None otherwise."""
    from pathlib import Path

    from payload_agent.errors import BaselineError
    from payload_agent.evaluation.baseline_identity import same_baseline
    from payload_agent.evaluation.calibration import effective_calibration
    from payload_agent.session.baseline import load_baseline

    cal = effective_calibration(config)
    try:
        stored = load_baseline(RobotState.for_config(config))
    except BaselineError:
        return None
    if cal is None or stored is None or not stored.source_run:
        return None
    if not same_baseline(cal.baseline_source, str(Path(stored.source_run).resolve())):
        return None
    return SharedBaseline(stored.plan_fingerprint, stored.procedure, float(stored.speed_percent))


def _effort_noise(config: Config) -> tuple[NoiseModel, str]:
    """Effort noise and friction (the stored baseline's, else the simulation's declared ones), with the sample
    density the stored runs delivered (``stream_density``; nominal without one)."""
    density = stream_density.delivered(config, stream_density.nominal_period_s(config, build_driver(config)))
    period, rate = density.period_s, density.describe()
    state = RobotState.for_config(config)
    if (state.baseline_dir / "empty").is_dir():
        from payload_agent.recording.rundata import load_manifest, load_phase

        try:
            manifest = load_manifest(state.baseline_dir)
            gains = np.asarray(manifest.get("gains_nm_per_unit") or config.effort.gains_nm_per_unit, float)
            empty = load_phase(state.baseline_dir, "empty", gains, manifest)
            moving, standing = moving_and_standing_std(empty)
            source = (f"effort noise (sweeping and standing joints apart) and friction measured in the stored "
                      f"baseline ({state.baseline_dir}); {rate}")
            return (NoiseModel(moving, period, length_std_m=config.robot.length_uncertainty_m, joints=config.robot.joints,
                               friction_level_nm=baseline_friction_nm(empty), effort_rest_std_nm=standing), source)
        except DataError:
            pass
    if config.simulation is not None:
        sim = config.simulation
        return (NoiseModel(tuple(sim.noise_nm), period, length_std_m=config.robot.length_uncertainty_m,
                           joints=config.robot.joints, friction_level_nm=tuple(sim.coulomb_nm),
                           effort_rest_std_nm=None if sim.noise_rest_nm is None else tuple(sim.noise_rest_nm)),
                f"effort noise and friction declared in the simulation section (no stored baseline); {rate}")
    raise ConfigError("--target-std", "no stored empty-flange baseline to measure the effort noise from: record one "
                                      "with `payload-agent baseline`, then plan for a target accuracy", config.source)


def baseline_friction_nm(empty) -> tuple[float, ...] | None:
    """Each joint's friction level in the baseline's sweeps (largest over its poses), for the
    residual-friction term of the prediction (``systematics.planned_covariance``)."""
    from payload_agent.evaluation.systematics.friction import friction_gaps

    level = [0.0] * 6
    for (_, j), gap in friction_gaps(empty).items():
        level[j] = max(level[j], abs(float(gap.level_nm)))
    return tuple(level) if any(level) else None


def plan_for_target(config: Config, text: str, payload: ExpectedPayload | None = None,
                    start_q=None, noise: tuple[NoiseModel, str] | None = None) -> tuple[Choice, str]:
    """The choice for ``--target-std TEXT`` and where its noise came from; ``start_q`` (where the robot stands,
    radians) makes every robot time count the approach move; ``noise``: ``noise_for(config)`` when the caller
    has it already."""
    grams, mm = parse_target(text)
    payload = payload or expected_payload(config)
    noise, source = noise or noise_for(config)
    from payload_agent.session.stored_candidate import grid_for

    return choose(config, grams, mm, noise, nominal_mass_kg=payload.mass_kg, nominal_cog_mm=payload.cog_mm,
                  grid=grid_for(config), start_q=start_q, from_rest=at_resting_pose(config, start_q)), source


def at_resting_pose(config: Config, start_q) -> bool:
    """Whether ``start_q`` is our own resting pose (``recording.resting_pose``): `run` then makes its first move at
    travel speed, and the plan counts the approach so."""
    return resting_pose.standing_at(RobotState.for_config(config).root, start_q) is not None


def plan_target(config: Config, args, start_q, con) -> dict:
    """``plan --target-std``'s part of the output: the payload assumed, the table with the chosen row, the
    chosen procedure written as a robot YAML in the state folder, and the command that runs it (JSON: the same)."""
    from payload_agent.session.target_file import procedure_keys, write_chosen

    grams, mm = parse_target(args.target_std)
    payload = expected_payload(config, args.payload_kg, args.payload_cog_mm, args.tool)
    where = "from where the robot stands"
    if start_q is None and config.simulation is not None:
        start_q, where = np.radians(config.simulation.start_deg), "from the simulation's start_deg"
    noise = noise_for(config)  # reads the stored baseline and calibration: once, for the choice and the advice
    choice, source = plan_for_target(config, args.target_std, payload, start_q, noise)
    from_rest = at_resting_pose(config, start_q)
    if from_rest:
        where += " (our own resting pose: the approach at travel speed)"
    con.say(f"Procedures for the target ({source}); predicted for the payload {payload.describe()}; robot time "
            + (f"with the approach move {where}:" if start_q is not None else
               "without the approach move (give --from-deg or --connect to count it):"))
    con.say(choice.describe(grams, mm))
    from payload_agent.evaluation.design import nominal_theta
    from payload_agent.session.target_advice import calibration_advice, park_advice

    advice = calibration_advice(config, choice, noise[0], nominal_theta(payload.mass_kg, payload.cog_mm),
                                grams, mm, start_q, from_rest)
    if advice:
        con.say(advice)
    parking = park_advice(config, choice, noise[0], nominal_theta(payload.mass_kg, payload.cog_mm), grams, mm)
    if parking:
        con.say(parking)
    out: dict = {"noise_source": source, "payload": {"mass_kg": payload.mass_kg, "cog_mm": list(payload.cog_mm),
                                                      "source": payload.source},
                 "approach_counted": start_q is not None, "approach_from_rest": from_rest, "chosen": None, "calibration_advice": advice or None,
                 "park_advice": parking or None}
    if choice.best is None:
        return out
    best = choice.best
    keys = procedure_keys(config, best.candidate)
    path = write_chosen(config, best.candidate, grams, mm,
                        f"payload-agent plan --target-std {grams:g},{mm:g}: {best.candidate.describe()}\n"
                        f"predicted 1σ of a typical run: mass {best.mass_std_g:.2f} g, centre of mass "
                        f"{best.cog_std_mm:.2f} mm (over the target in {100 * best.p_over(grams, mm):.0f} % of runs), "
                        f"{best.robot_time_s:.0f} s of robot time, for the payload {payload.describe()}\n"
                        f"{config.source} with its procedure section replaced")
    con.say("The chosen procedure's keys (the robot YAML's `procedure:` section): "
            + ", ".join(f"{k}: {v}" for k, v in keys.items()))
    con.say(f"Written with the rest of {config.source} to {path}; run it with:\n"
            f"  payload-agent run --robot {path}")
    from payload_agent.evaluation.design import run_config

    inertia = run_config(config, best.candidate).procedure.inertia
    if best.candidate.stored_baseline:
        con.say("It is the stored baseline's plan: its run reuses the stored empty-flange run (records none of its "
                "own)" + (", the one the drive-gain calibration subtracted" if noise[0].shared_baseline else "")
                + ("" if inertia == config.procedure.inertia else
                   f"; its inertia part as that baseline recorded it ({inertia or 'off'}, the YAML: "
                   f"{config.procedure.inertia or 'off'})"))
    if inertia is not None:
        con.say(f"The robot time above is the mass and centre-of-mass part; the written file keeps "
                f"procedure.inertia ({inertia}), whose wrist moves come on top (`plan` shows them).")
    out["chosen"] = {"procedure": best.candidate.describe(), "robot_time_s": best.robot_time_s,
                     "mass_std_g": best.mass_std_g, "cog_std_mm": best.cog_std_mm,
                     "mass_rms_std_g": best.mass_rms_std_g, "cog_rms_std_mm": best.cog_rms_std_mm,
                     "p_over_target": best.p_over(grams, mm), "procedure_keys": keys,
                     "robot_file": str(path), "inertia_part": inertia,
                     "reuses_stored_baseline": best.candidate.stored_baseline}
    return out
