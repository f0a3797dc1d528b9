"""One benchmark case: a seeded simulated EC66, a payload, a procedure, every method's estimate.

The machinery behind ``benchmarks.accuracy`` (whose docstring describes scenarios and methods):
the simulated robot's draws per case, offline recording, the agent's own pipeline, the quality
gate, one result row per method.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np

from benchmarks import hard
from benchmarks.gate import gate
from benchmarks.hard import ABLATION_SCENARIOS, HARD, STRONG
from benchmarks.reference import REFERENCE, calibrate, theta_reference
from benchmarks.remedies import COMP, COMP3, comp_estimate
from benchmarks.tables import EXCITATION_LABEL

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "sim-ec66.yaml"
SPEEDS = (1.0, 5.0, 10.0, 20.0)
SCENARIOS = ("ideal", "realistic", HARD, STRONG)
# ablations, only with --scenarios: realistic but with exact drive gains (what `calibrate` would buy);
# realistic plus one error source of a real arm (benchmarks/hard.py)
ALL_SCENARIOS = (*SCENARIOS, "realistic-exact-gains", *ABLATION_SCENARIOS)
METHODS = ("three-step", "general-up", "general-bi", "general-bi-cal", COMP, COMP3, "dynamic")
PTP_METHODS = METHODS[:6]
NOISE_NM = 0.3
COULOMB_NM = (4.0, 4.0, 3.0, 1.0, 1.0, 0.5)
VISCOUS_NM_S_RAD = (8.0, 8.0, 5.0, 1.0, 1.0, 0.5)
TICK_S = 0.008  # the Elite monitor's sample period
DH_ERROR_MM = 0.5  # realistic scenarios: every non-zero DH length off by uniform ±this
GAIN_ERROR = 0.03  # realistic scenario: every drive gain off by uniform ±this (relative)
CHI2_3_95 = 7.814727903251178  # 95 % quantile of χ² with 3 degrees of freedom
# speed rows: the procedure of configs/sim-ec66.yaml when this benchmark was set up (pinned here so
# that editing the config does not silently change the benchmark)
SPEED_ROW_TRAVEL, SPEED_ROW_ACCEL, SWEEP_DEG = 10.0, 20.0, (0.0, 55.0)
# the recommended default procedure (docs/benchmarks.md): rows labelled "default"
RECOMMENDED_DEFAULT = "speed=10,travel=20,accel=20,sweep=0:55"


@dataclasses.dataclass(frozen=True)
class Procedure:
    """The procedure knobs the benchmark varies (percentages of max joint speed / acceleration)."""

    label: str  # row label: the speed ("5") or "default"
    speed: float
    travel: float
    accel: float
    sweep_from: float
    sweep_to: float

    def describe(self) -> str:
        return (f"sweep {self.speed:g} %, travel {self.travel:g} %, accel {self.accel:g} %, "
                f"range {self.sweep_from:g}–{self.sweep_to:g}°")


def payloads(n: int, seed: int = 2025) -> list[tuple[float, tuple[float, float, float]]]:
    """n seeded payloads: 0.5–5 kg, centre of mass anywhere within 150 mm of the flange centre."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        m = float(rng.uniform(0.5, 5.0))
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        r = float(rng.uniform(0.0, 150.0))
        if d[2] < 0:  # tools stick out of the flange: keep z positive
            d[2] = -d[2]
        out.append((m, tuple(float(v) for v in d * r)))
    return out


def _config(proc: Procedure, bidirectional: bool):
    from payload_agent.configuration.config import load_config

    config = load_config(CONFIG)
    pc = dataclasses.replace(config.procedure, speed_percent=proc.speed, travel_speed_percent=proc.travel,
                             accel_percent=proc.accel, sweep_from_deg=proc.sweep_from, sweep_to_deg=proc.sweep_to,
                             bidirectional=bidirectional)
    return dataclasses.replace(config, procedure=pc)


@functools.lru_cache(maxsize=None)
def plans(proc: Procedure):
    """(bidirectional plan, unidirectional plan, bidirectional config), once per worker and procedure."""
    from payload_agent.motion.planner import make_plan

    config_bi = _config(proc, True)
    return make_plan(config_bi), make_plan(_config(proc, False)), config_bi


def motion_time_s(plan) -> float:
    """Robot time of one run without the approach move (the design's own count)."""
    from payload_agent.motion.planner import robot_time_s

    return robot_time_s(plan)


def check_safety(proc: Procedure) -> list[str]:
    """The safety gate's problems with this procedure's bidirectional plan (empty: it would run)."""
    from payload_agent.motion.planner import make_plan
    from payload_agent.motion.safety import SafetyGate

    config = _config(proc, True)
    plan = make_plan(config)
    verdict = SafetyGate(config).check(plan, np.asarray(plan.moves[0].target_rad))
    return list(verdict.problems)


def robot_draws(scenario: str, index: int) -> dict:
    """The simulated robot's imperfections for one case: the same for every procedure."""
    from payload_agent.fakes.arms import SPECS

    seed_scenario = ("ideal", "realistic").index(base_scenario(scenario))
    rng = np.random.default_rng([index, seed_scenario, 7])
    spec = SPECS["ec66"]()
    if base_scenario(scenario) == "realistic":
        spec = spec.with_dh_errors(rng, DH_ERROR_MM / 1000.0)
        gain = rng.uniform(1.0 - GAIN_ERROR, 1.0 + GAIN_ERROR, 6)
        if scenario == "realistic-exact-gains":
            gain = np.ones(6)
        drift_load, drift_ref = (float(v) for v in rng.uniform(-0.10, 0.10, 2))
        load_ratio = 0.05
    else:
        gain, drift_load, drift_ref, load_ratio = np.ones(6), 0.0, 0.0, 0.0
    out = {"spec": spec, "gain": gain, "drift_load": drift_load, "drift_ref": drift_ref,
           "load_ratio": load_ratio, "noise_seed": int(rng.integers(2**31)), "effects": None,
           "effects_ref": None, "declared": None}
    extra = hard.draw(scenario, index)
    if extra is not None:
        out["effects"], out["effects_ref"], out["declared"] = extra
    return out


def base_scenario(scenario: str) -> str:
    """"ideal" or "realistic": the hard and ablation scenarios are the realistic arm plus effects."""
    return "ideal" if scenario == "ideal" else "realistic"


def declared_length_std_mm(scenario: str, override: float | None = None) -> float:
    """The DH-length standard uncertainty the agent is configured with (``--length-uncertainty-mm``).

    Default: the simulated arm's own, i.e. the standard deviation of its uniform ±DH_ERROR_MM
    length errors in the realistic scenarios and 0 in "ideal" (exact lengths).
    """
    if override is not None:
        return float(override)
    return DH_ERROR_MM / math.sqrt(3.0) if base_scenario(scenario) == "realistic" else 0.0


def declared_unfitted_gain_std(scenario: str, override_percent: float | None = None) -> float:
    """Relative gain uncertainty the agent declares for joints its calibration does not fit.

    Default: the simulated arm's own, the standard deviation of its uniform ±GAIN_ERROR gain errors
    in "realistic" and 0 where the gains are exact ("ideal", "realistic-exact-gains"), as the
    DH-length term (``declared_length_std_mm``). The agent's own default is ``UNFITTED_GAIN_REL_STD``.
    """
    if override_percent is not None:
        return float(override_percent) / 100.0
    return GAIN_ERROR / math.sqrt(3.0) if scenario not in ("ideal", "realistic-exact-gains") else 0.0


def _robot(draws: dict, start: np.ndarray, seed_extra: int):
    from payload_agent.fakes.physics import FrictionParams
    from payload_agent.fakes.sim_robot import SimRobot

    friction = FrictionParams(np.array(COULOMB_NM), np.array(VISCOUS_NM_S_RAD), np.full(6, draws["load_ratio"]))
    return SimRobot(draws["spec"], q0_rad=start, tick_s=TICK_S, friction=friction, noise_nm=NOISE_NM,
                    seed=int(np.random.default_rng([draws["noise_seed"], seed_extra]).integers(2**31)), payload=None,
                    effects=draws["effects"])


def _row(base: dict, est, mass: float, cog_mm, motion: float) -> dict:
    """Errors, reported uncertainty and interval coverage of one estimate."""
    from payload_agent.solvers.wls import cog_with_covariance

    dm = est.mass_kg - mass
    dc = np.asarray(est.cog_m) - np.asarray(cog_mm) / 1000.0
    row = dict(base, mass_kg=mass, cog_mm=list(cog_mm), est_mass_kg=est.mass_kg, est_cog_mm=list(est.cog_mm),
               mass_err_g=1000 * dm, cog_err_mm=float(1000 * np.linalg.norm(dc)), motion_time_s=motion,
               mass_std_g=None, cog_std_mm=None, z_mass=None, z_cog=None, mass_in_ci95=None, cog_in_ci95=None)
    if est.mass_std_kg is not None and est.mass_std_kg > 0:
        row.update(mass_std_g=1000 * est.mass_std_kg, z_mass=dm / est.mass_std_kg,
                   mass_in_ci95=bool(abs(dm) <= 1.959964 * est.mass_std_kg))
    if est.cog_std_m is not None and est.covariance is not None:
        row.update(cog_std_mm=[1000 * v for v in est.cog_std_m],
                   z_cog=(dc / np.maximum(np.asarray(est.cog_std_m), 1e-15)).tolist())
        theta = np.array([est.mass_kg, *(est.mass_kg * np.asarray(est.cog_m))])
        _, cov_c = cog_with_covariance(theta, np.asarray(est.covariance)[:4, :4])
        try:
            d2 = float(dc @ np.linalg.solve(cov_c, dc))
            row["cog_in_ci95"] = bool(d2 <= CHI2_3_95)  # 95 % confidence ellipsoid of c
        except np.linalg.LinAlgError:
            pass
    return row


def _scaled(deltas: dict, scale: np.ndarray) -> dict:
    from payload_agent.analysis.delta import DeltaSweep

    return {k: DeltaSweep(d.key, d.q, d.dtau * scale, d.speed_rad_s) for k, d in deltas.items()}


def record_reference(robot, plan_bi, draws) -> dict:
    """The calibration run with the reference payload on the same robot (its own friction drift draw;
    in the hard scenarios no cable and its own warm-up)."""
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth

    robot.set_payload(PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    robot.set_friction_scale(1.0 + draws["drift_ref"])
    tool_effects = robot.effects
    if draws["effects_ref"] is not None:
        robot.effects = draws["effects_ref"]
    try:
        ref, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])
    finally:
        robot.effects = tool_effects
    return ref


def run_case(args: tuple) -> list[dict]:
    """One payload, one scenario, one procedure: every PTP method's estimate."""
    scenario, proc, methods, index, mass, cog_mm, *rest = args
    length_std_mm = declared_length_std_mm(scenario, rest[0] if rest else None)
    unfitted_std = declared_unfitted_gain_std(scenario, rest[1] if len(rest) > 1 else None)
    replica = int(rest[2]) if len(rest) > 2 else 0  # > 0: the same arm and payload, another sensor-noise draw
    kin_kw = {"length_std_m": length_std_mm / 1000.0}
    from payload_agent.analysis.combine import add_combined
    from payload_agent.analysis.delta import subtract_all
    from payload_agent.errors import PayloadAgentError
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.solvers import general, three_step

    draws = robot_draws(scenario, index)
    if replica:
        draws["noise_seed"] = int(np.random.default_rng([draws["noise_seed"], replica]).integers(2**31))
    plan_bi, plan_up, config_bi = plans(proc)
    kin = config_bi.robot.kinematics
    start = np.asarray(plan_bi.moves[0].target_rad)
    robot = _robot(draws, start, int(round(proc.speed * 100)) + 7919 * int(round(proc.travel * 100 + proc.accel)))
    empty, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])
    robot.set_payload(PayloadTruth.point(mass, cog_mm))
    mount = np.asarray(robot.snapshot().q, float)  # where the loaded run starts, as the agent records it
    robot.set_friction_scale(1.0 + draws["drift_load"])
    loaded, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])

    base = {"scenario": scenario, "procedure": proc.label, "procedure_settings": dataclasses.asdict(proc),
            "payload": index, "noise_draw": replica, "length_std_mm": length_std_mm}
    if "general-bi-cal" in methods or COMP in methods or COMP3 in methods:
        base["unfitted_gain_std_percent"] = 100.0 * unfitted_std
    rows = []
    try:
        deltas = subtract_all(loaded, empty)
        combined, _ = add_combined(deltas)
    except PayloadAgentError as exc:
        return [dict(base, method=m, error=str(exc)) for m in methods]
    up_only = {k: d for k, d in deltas.items() if k.direction == "up"}
    reference: list = []  # the reference run, recorded once for the methods that calibrate

    def ref_run():
        if not reference:
            reference.append(record_reference(robot, plan_bi, draws))
        return reference[0]

    for method in methods:
        # the quality gate sees what the agent's analysis would: the method's deltas, the declared DH-length
        # uncertainty and, after a calibration, the calibrated gains, their uncertainty and the reference
        gate_deltas, gate_kw = (combined if method in ("general-bi", "general-bi-cal") else up_only), dict(kin_kw)
        try:
            if method == "three-step":
                est, plan = three_step.solve(up_only, kin), plan_up
            elif method == "general-up":
                est, plan = general.solve(up_only, kin, **kin_kw), plan_up
            elif method == "general-bi":
                est, plan = general.solve(combined, kin, **kin_kw), plan_bi
            elif method == "general-bi-cal":
                scale, gain_rel_std, fitted = calibrate(ref_run(), empty, config_bi, unfitted_std)
                gate_deltas = _scaled(combined, scale)
                gate_kw.update(gain_rel_std=list(gain_rel_std), gain_reference=(theta_reference(), fitted))
                est, plan = general.solve(gate_deltas, kin, name="general-bi-cal", **gate_kw), plan_bi
            elif method in (COMP, COMP3):
                est, gate_cols = comp_estimate(loaded, empty, ref_run(), draws["declared"], config_bi, unfitted_std,
                                               kin_kw, "general" if method == COMP else "three-step", mount)
                rows.append(dict(_row(dict(base, method=method), est, mass, cog_mm, motion_time_s(plan_bi)), **gate_cols))
                continue
            else:
                raise ValueError(method)
        except PayloadAgentError as exc:
            rows.append(dict(base, method=method, error=str(exc)))
            continue
        row = dict(_row(dict(base, method=method), est, mass, cog_mm, motion_time_s(plan)),
                   **gate(gate_deltas, kin, est, **gate_kw))
        if "gain_rel_std" in gate_kw:
            row["gain_rel_std"] = [float(v) for v in gate_kw["gain_rel_std"]]
            row["fitted_joints"] = [int(j) for j in gate_kw["gain_reference"][1]]
        rows.append(row)
    return rows


@functools.lru_cache(maxsize=None)
def _excitation_trajectory():
    from payload_agent.fakes.arms import SPECS
    from benchmarks.excitation import default_start, design_trajectory
    from payload_agent.model.kinematics import Kinematics

    kin = Kinematics(SPECS["ec66"]().dh)  # the experimenter designs on the nominal model
    return design_trajectory(kin, default_start(kin), seed=1)


def run_dynamic_case(args: tuple) -> list[dict]:
    """One payload, one scenario: the dynamic baseline along the excitation trajectory."""
    scenario, index, mass, cog_mm = args
    from payload_agent.configuration.config import load_config
    from payload_agent.errors import PayloadAgentError
    from benchmarks.excitation import record_excitation
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.solvers import dynamic

    draws = robot_draws(scenario, index)
    traj = _excitation_trajectory()
    kin = load_config(CONFIG).robot.kinematics
    robot = _robot(draws, traj.q_start, 424242)
    empty, _ = record_excitation(robot, traj, torque_scale=draws["gain"])
    robot.set_payload(PayloadTruth.point(mass, cog_mm))
    robot.set_friction_scale(1.0 + draws["drift_load"])
    loaded, motion = record_excitation(robot, traj, torque_scale=draws["gain"])
    base = {"scenario": scenario, "procedure": EXCITATION_LABEL, "method": "dynamic", "payload": index,
            "procedure_settings": {"trajectory_s": traj.duration_s, "period_s": traj.period_s,
                                   "harmonics": int(traj.a.shape[1])}}
    try:
        est = dynamic.solve(_uniform(loaded), _uniform(empty), kin)
    except PayloadAgentError as exc:
        return [dict(base, error=str(exc))]
    return [_row(base, est, mass, cog_mm, motion)]


def _uniform(rec):
    """A record with jittered timestamps resampled onto its nominal uniform grid (what the dynamic
    solver asks for: "resample first"); linear interpolation, a no-op without jitter."""
    t = np.asarray(rec.t, float)
    grid = t[0] + np.arange(len(t)) * float(np.median(np.diff(t)))
    if np.allclose(grid, t, rtol=0.0, atol=1e-12):
        return rec
    cols = lambda a: np.column_stack([np.interp(grid, t, a[:, c]) for c in range(a.shape[1])])  # noqa: E731
    return dataclasses.replace(rec, t=grid, q=cols(np.asarray(rec.q)), effort_nm=cols(np.asarray(rec.effort_nm)))


def _dispatch(case: tuple) -> list[dict]:
    kind, args = case
    return run_dynamic_case(args) if kind == "dynamic" else run_case(args)
