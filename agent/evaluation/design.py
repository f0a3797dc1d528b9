"""A procedure chosen for a target accuracy: predict σ of each candidate before moving, pick the fastest.

For a candidate procedure (which poses and sweeps: a procedure file; sweep speed, travel speed, acceleration, sweep
range, repetitions) the plan is made as ``plan`` would make it; every sweep's constant-speed samples are placed where
the segmenter will find them (the commanded profile's cruise interval, ``SweepCommand.cruise_interval``, sampled at
the controller's period), and the general solver's regressor is evaluated there for a nominal
payload. With white effort noise σ_j per joint (declared, or measured in the stored baseline by
``measured_effort_std``; a joint standing while another sweeps has its own, lower on a UR), present in the loaded and the empty run alike (variance doubled by the
subtraction), the two legs of a bidirectional sweep averaged (halved) and ``repetitions`` runs of
the procedure, the information matrix is Σ YᵀY/σ², and

    Cov θ ≈ (Σ YᵀY/σ²)⁻¹ · inflation² + the systematic terms (drive gains, DH lengths),

the same terms ``general.solve`` reports, plus those of ``evaluation.systematics`` that can be
predicted before the run (``systematics.planned_covariance``: joint zeros) and the expectation of the
run's data-sized ones (``planned_terms``: the wrist torques, and the residual friction with the change as
the run will measure it, an earlier run's measurement standing in for the truth when there is one; the
stiffness term is not predicted, the gain-scatter term only for the clusters standing at the angles whose gain errors
the calibration measured, ``planned_scatter``), and the calibration's shared empty run where the candidate's
run will subtract it (``planned_baseline``). ``inflation`` is the ratio of the reported
(autocorrelation-robust) to the white-noise σ a run of this arm showed (``noise_inflation``: the stored
calibration run's own fit; 1 without one).
σ of the mass and of the centre of mass (largest axis) follow by the delta method, per seeded draw of the wrist
term (the run's own rule) and of the run's own estimate of its noise term (``noise_scatter``: a few % between
runs; and the plan's own inflation, one stored run's estimate of it: ``NoiseScatter.with_estimate``): a typical
run's (median) is the prediction, and ``TARGET_RISK`` the choice's bound on the chance the run's
σ exceeds the target.

``choose`` evaluates a grid of candidates, keeps those the safety gate accepts (the whole plan,
as ``plan`` checks it, the approach too when where the robot stands is given), and returns the one
that meets the target in the least robot time (the approach move counted then: procedures start in
different poses), with the whole trade-off table. The procedures tried are the configured one and the bundled procedures of
``PROCEDURES``: joint-2 sweeps only in two or three tool orientations (procedures/j2_pair.yaml,
j2_triple.yaml, j2_quarter.yaml), which carry the payload's weight on the longest lever (links 2 and 3 collinear) and
need no 90° joint-2 travel to a joint-3 sweep's start. ``covariance_terms`` keeps each part
of a prediction apart (``benchmarks.plan_budget``). The CLI hook is ``plan --target-std G,MM``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.configuration.config import Config, JointSystematicsConfig
from payload_agent.evaluation.effort_noise import measured_effort_std  # noqa: F401
from payload_agent.evaluation.candidates import (ACCELS_PERCENT, CONFIGURED, PROCEDURES, RANGES_DEG,  # noqa: F401
                                                 REPETITIONS, SPEEDS_PERCENT, TRAVEL_PERCENT, Candidate, candidates,
                                                 candidates_for)
from payload_agent.evaluation.noise_scatter import NoiseScatter, scatter
from payload_agent.evaluation.planned_baseline import SharedBaseline, reusing_run_mount
from payload_agent.evaluation.planned_samples import planned_sweeps, too_few_samples  # noqa: F401
from payload_agent.evaluation.planned_scatter import corrected_covariance
from payload_agent.evaluation.planned_terms import (DRAWS, FrictionKnowledge, WristModel, friction_covariance,
                                                    reported_sigma_draws, wrist_model, cable_declared,
                                                    cable_absent)
from payload_agent.motion.planner import Plan, from_resting_pose, make_plan, move_duration_s, robot_time_s, turned_to


# The largest chance that the run's reported σ exceeds the target (mass or CoM) with which a candidate meets it.
# The wrist term appears in ~31 % of clean runs whatever the procedure (P(⅚·χ²_r > r), r ≤ 4): above that this
# is a choice on the median; 0.2 keeps the target in 4 of 5 runs (docs/benchmarks.md, "Session 13").
TARGET_RISK = 0.2


@dataclass(frozen=True)
class Prediction:
    """One candidate's predicted σ: the reported σ's medians over its draws (``planned_terms.reported_sigma_draws``),
    the root of its expected variance (``_rms_``: what ``covariance_terms`` add to) and the draws (σ m g, σ c mm)."""

    candidate: Candidate
    robot_time_s: float  # loaded run, the approach move included when where the robot stands is known
    mass_std_g: float  # median over the draws
    cog_std_mm: float  # largest axis, median over the draws
    samples: int  # constant-speed samples per run (all sweeps)
    problems: tuple[str, ...] = ()  # the safety gate's, or why it cannot be predicted
    approach_s: float = 0.0  # the part of robot_time_s that is the approach move (0: not counted)
    mass_rms_std_g: float = float("nan")
    cog_rms_std_mm: float = float("nan")
    draws: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)  # (n, 2)

    @property
    def usable(self) -> bool:
        return not self.problems

    def p_over(self, mass_std_g: float, cog_std_mm: float) -> float:
        """The chance that the run's reported σ of the mass or of the centre of mass (largest axis) exceeds the
        target, over the draws of the wrist term and of the run's own noise estimate (the rest of σ as predicted)."""
        if self.draws is None:
            return float(self.mass_std_g > mass_std_g or self.cog_std_mm > cog_std_mm)
        over = (self.draws[:, 0] > mass_std_g) | (self.draws[:, 1] > cog_std_mm)
        return float(np.mean(over))

    def meets(self, mass_std_g: float, cog_std_mm: float) -> bool:
        return self.usable and self.p_over(mass_std_g, cog_std_mm) <= TARGET_RISK


@dataclass(frozen=True)
class NoiseModel:
    """What the prediction assumes about the data."""

    effort_std_nm: tuple[float, ...]  # white effort noise per joint, N·m (the joint sweeping)
    sample_period_s: float
    inflation: float = 1.0  # reported (autocorrelation-robust) σ / white-noise σ of a previous run
    gain_rel_std: tuple[float, ...] | None = None  # drive-gain uncertainty (after a calibration)
    # the gains are the controller's own current-to-torque constants (a UR without a calibration,
    # ``controller_gains``): a run fits them, and carries their uncertainty, for the joints that sweep in it only
    gain_swept_only: bool = False
    length_std_m: float = 0.0  # DH-length standard uncertainty
    # the drive-gain calibration's reference (``GainCalibration.reference``: θ_ref, fitted joints, ..., its measured
    # response to the DH lengths when stored), whose fit absorbed part of the length errors
    gain_reference: tuple | None = None
    # evaluation.systematics' declarations (config.robot.joints: zero uncertainty, friction asymmetry and
    # change) and each joint's friction level (N·m: the stored baseline's, or the simulation's Coulomb
    # friction; None: the residual-friction term is not predicted)
    joints: JointSystematicsConfig | None = None
    friction_level_nm: tuple[float, ...] | None = None
    # an earlier run's measured friction change (``planned_terms.earlier_friction_change``; None: the prior)
    friction_known: FrictionKnowledge | None = None
    # the noise of a joint standing while another one sweeps (a UR's is 2-5x lower: docs/sources.md); its rows
    # carry the payload's torque too. None: as while it moves
    effort_rest_std_nm: tuple[float, ...] | None = None
    # the relative standard deviation of ``inflation``, itself one run's ratio (``noise_inflation``); last, so that
    # the fields before it keep their positions
    inflation_rel_std: float = 0.0
    # the stored baseline, where the stored calibration subtracted it too: a run of its plan reuses it and shares its
    # noise with the calibration (``SharedBaseline``); None: every run's empty run independent of the calibration's
    shared_baseline: SharedBaseline | None = None


def with_candidate(config: Config, c: Candidate) -> Config:
    pc = dataclasses.replace(config.procedure, speed_percent=c.speed_percent, travel_speed_percent=c.travel_percent,
                             sweep_from_deg=c.sweep_from_deg, sweep_to_deg=c.sweep_to_deg,
                             accel_percent=c.accel_percent, name=c.procedure or config.procedure.name,
                             inertia=None)  # the mass/CoM procedure only: the inertia part is the same in every one
    return dataclasses.replace(config, procedure=pc)


_PLANS: dict[tuple, Plan] = {}


def plan_for(config: Config, c: Candidate) -> Plan:
    """``make_plan`` for the candidate: one plan per procedure and sweep range, its sweep and travel
    speeds and acceleration set per candidate (the moves' targets do not depend on them)."""
    from payload_agent.types import SweepKey

    key = (id(config), config.source, c.procedure, c.sweep_from_deg, c.sweep_to_deg)
    if key not in _PLANS:
        if len(_PLANS) > 64:
            _PLANS.clear()
        _PLANS[key] = make_plan(with_candidate(config, c))
    base = _PLANS[key]
    vmax = config.robot.max_joint_speed_rad_s
    accel = config.robot.max_joint_accel_rad_s2 * c.accel_percent / 100.0
    moves = []
    for m in base.moves:
        if m.kind == "sweep":
            sk = m.sweep
            m = dataclasses.replace(m, speed_rad_s=vmax * c.speed_percent / 100.0,
                                    sweep=SweepKey(sk.pose, sk.joint, sk.direction, c.speed_percent))
        elif m.kind == "travel":
            m = dataclasses.replace(m, speed_rad_s=vmax * c.travel_percent / 100.0)
        moves.append(dataclasses.replace(m, accel_rad_s2=accel))
    return dataclasses.replace(base, moves=tuple(moves))


def run_config(config: Config, c: Candidate) -> Config:
    """The config a run of the candidate uses: the written robot YAML keeps ``procedure.inertia`` unless it sets it."""
    cfg, inertia = with_candidate(config, c), config.procedure.inertia if c.inertia == CONFIGURED else c.inertia
    return dataclasses.replace(cfg, procedure=dataclasses.replace(cfg.procedure, inertia=inertia))


# the named parts of a prediction (``covariance_terms``): the first two shrink with repetitions, the rest do not
# ("baseline": the empty run the calibration shared, the same one in every repetition)
NOISE_TERMS = ("noise", "wrist")
SYSTEMATIC_TERMS = ("friction", "gains", "lengths", "zeros", "baseline", "scatter")


def covariance_terms(config: Config, plan: Plan, noise: NoiseModel, theta: np.ndarray, *, shared: bool = False
                     ) -> tuple[dict[str, np.ndarray], int]:
    """Each part of the predicted covariance of θ for one run, by name (``NOISE_TERMS``, ``SYSTEMATIC_TERMS``; the
    wrist term as its expectation), and the constant-speed samples of one run: kept apart so that a benchmark can
    show what binds a candidate (docs/benchmarks.md, issue 22); ``shared`` as for ``terms_and_wrist_model``."""
    terms, n, _, _ = terms_and_wrist_model(config, plan, noise, theta, shared=shared)
    return terms, n


def terms_and_wrist_model(config: Config, plan: Plan, noise: NoiseModel, theta: np.ndarray, *, shared: bool = False,
                          mount_rad=None) -> tuple[dict[str, np.ndarray], int, WristModel, NoiseScatter]:
    """``covariance_terms``, the wrist term the run will fit (``planned_terms.WristModel``: a tool cable's spring
    relaxed where the loaded run starts: where its own empty run ended, or ``mount_rad``, where the robot stands, for a
    run that reuses the stored baseline) and the scatter of the run's own noise estimate (``noise_scatter``), from
    which ``predict`` draws the σ a run reports. ``shared``: the run subtracts the calibration's empty run
    (``planned_baseline``), and its σ carries the correlation of the two (``shared_baseline.planned_cross_covariance``, "baseline"; 0 otherwise)."""
    from payload_agent.solvers import general, length_response, wls

    kin = config.robot.kinematics
    sweeps = planned_sweeps(plan, noise.sample_period_s)
    groups = general.build_groups(sweeps, kin)
    std = np.broadcast_to(np.asarray(noise.effort_std_nm, float), (6,))
    rest = std if noise.effort_rest_std_nm is None else np.broadcast_to(np.asarray(noise.effort_rest_std_nm, float), (6,))
    by_name = {d.key.name: d for d in sweeps}
    w_rows = []
    for g in groups:
        # loaded minus empty: both runs' noise (the empty run's, interpolated, a little less: taken as
        # equal); the two legs of a bidirectional sweep averaged: half of it. The sweeping joint's noise, or
        # a standing joint's
        d = by_name[g.sweep]
        sigma = std[g.joint] if g.joint == d.moving else rest[g.joint]
        var = 2.0 * sigma ** 2 * (0.5 if d.key.direction == "both" else 1.0)
        w_rows.append(np.full(len(g.y), 1.0 / max(var, 1e-30)))
    w = np.concatenate(w_rows)
    Y = np.vstack([g.Y for g in groups])
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)
    J = np.zeros((3, 4))  # the delta method's Jacobian of c = θ[1:]/θ[0]: the CoM's largest axis of the noise term
    J[:, 0], J[:, 1:] = -theta[1:] / theta[0] ** 2, np.eye(3) / theta[0]
    axis = int(np.argmax(np.diag(J @ inv @ J.T)))
    spread = scatter(groups, w, inv, np.vstack([np.eye(4)[0], J[axis]]), noise.inflation, DRAWS,
                     both={d.key.name: d.key.direction == "both" for d in sweeps}).with_estimate(
        noise.inflation_rel_std)  # and the plan's inflation, itself one run's estimate
    # the run's noise term on average: the kernel ratio it keeps only above 1 (``NoiseScatter.kept``, the mass's)
    terms = {"noise": inv * noise.inflation ** 2 * spread.kept[0]}
    # the terms the run sizes from its data, as it will on average (``planned_terms``): they depend on the
    # noise and the samples, so per candidate
    rel = noise.gain_rel_std
    if rel is not None and noise.gain_swept_only:
        swept = {m.sweep.joint - 1 for m in plan.sweeps}
        rel = tuple(r if j in swept else 0.0 for j, r in enumerate(rel))
    wrist = wrist_model(sweeps, groups, w, noise.inflation, theta, rel,
                        plan.moves[-1].target_rad if mount_rad is None else mount_rad, cable_declared(noise.joints),
                        cable_absent(noise.joints))
    terms["wrist"] = wrist.expected()
    terms["friction"] = np.zeros((4, 4))
    terms["baseline"] = np.zeros((4, 4))
    # the torque-gain term of the clusters standing at the calibration's angles, σ_ε each (``planned_scatter``)
    terms["scatter"] = corrected_covariance(sweeps, groups, w, inv, theta, noise.gain_reference)
    if shared and noise.gain_reference is not None and rel is not None:
        from payload_agent.evaluation.shared_baseline import planned_cross_covariance

        terms["baseline"] = planned_cross_covariance(groups, w, theta, noise.gain_reference[0],
                                                     noise.gain_reference[1], rel)
    decl, level = noise.joints, noise.friction_level_nm
    if decl is not None and level is not None:
        terms["friction"] = friction_covariance(sweeps, groups, w, theta, float(decl.friction_asymmetry_std),
                                                float(decl.friction_change_std), dict(enumerate(level)), std,
                                                noise.inflation, noise.friction_known)
    # the systematic terms do not shrink with more samples; they depend on where the samples lie
    # (procedure and sweep range) and hardly on the speed: computed once per range (the DH-length part is slow)
    ref = None if noise.gain_reference is None else (tuple(noise.gain_reference[0]), tuple(noise.gain_reference[1]),
                                                     length_response.of_reference(noise.gain_reference))
    # (keyed by what the terms depend on, the calibration's measured length response too: not the config object)
    key = (config.source, repr(config.robot.dh), plan.procedure.fingerprint,
           plan.moves[1].target_rad if len(plan.moves) > 1 else None,
           tuple(theta), rel, noise.length_std_m, ref, repr(noise.joints))
    if key not in _SYSTEMATIC:
        fixed = {name: np.zeros((4, 4)) for name in ("gains", "lengths", "zeros")}
        if rel is not None:
            fixed["gains"] = wls.gain_covariance(groups, Y, w, inv, theta, rel)
        if noise.length_std_m > 0:
            fixed["lengths"] = general.kinematic_covariance(sweeps, kin, groups, w, inv, theta, noise.length_std_m,
                                                            noise.gain_reference)
        if noise.joints is not None:
            # evaluation.systematics' own prediction for a planned procedure, joint zeros only: the residual
            # friction is ``friction`` above (the change as the run will measure it)
            from payload_agent.evaluation import systematics

            fixed["zeros"] = systematics.planned_covariance(sweeps, kin, noise.joints, theta, w, None)
        if len(_SYSTEMATIC) > 256:
            _SYSTEMATIC.clear()
        _SYSTEMATIC[key] = fixed
    return {**terms, **_SYSTEMATIC[key]}, sum(len(d.q) for d in sweeps), wrist, spread


_SYSTEMATIC: dict[tuple, dict[str, np.ndarray]] = {}


def nominal_theta(mass_kg: float, cog_mm: Sequence[float]) -> np.ndarray:
    return np.array([mass_kg, *(mass_kg * np.asarray(cog_mm, float) / 1000.0)])


def predict(config: Config, c: Candidate, noise: NoiseModel, theta: np.ndarray, *, check_safety: bool = True,
            start_q: Sequence[float] | None = None, from_rest: bool = False) -> Prediction:
    """σ of one candidate; its robot time counts the approach from ``start_q`` once when that is given (at travel
    speed ``from_rest``: the arm stands at our own resting pose)."""
    from payload_agent.solvers.wls import cog_with_covariance

    base = _one_run(config, dataclasses.replace(c, repetitions=1), noise, theta, check_safety, start_q)
    if isinstance(base, tuple) and len(base) == 1:
        return Prediction(c, float("nan"), float("nan"), float("nan"), 0, base[0])
    time_s, noise_cov, wrist, sys_cov, n, problems, spread = base
    cov = noise_cov / c.repetitions + sys_cov
    wrist = wrist.over(c.repetitions)
    sigma_m, sigma_c = reported_sigma_draws(cov, wrist, theta, noise_cov / c.repetitions, spread.over(c.repetitions))
    mean_cov = cov + wrist.expected()
    _, cov_c = cog_with_covariance(theta, mean_cov)
    approach = approach_s(config, c, start_q, from_rest)
    return Prediction(c, c.repetitions * time_s + approach, float(np.median(sigma_m)), float(np.median(sigma_c)), n,
                      problems, approach, 1000.0 * math.sqrt(max(mean_cov[0, 0], 0.0)),
                      1000.0 * math.sqrt(max(float(np.max(np.diag(cov_c))), 0.0)), np.column_stack([sigma_m, sigma_c]))


_RUNS: dict[tuple, tuple] = {}


def approach_s(config: Config, c: Candidate, start_q: Sequence[float] | None, from_rest: bool = False) -> float:
    """The approach move of the candidate's plan from ``start_q`` (0 when where the robot stands is unknown)."""
    if start_q is None:
        return 0.0
    plan = turned_to(config, plan_for(config, c), np.asarray(start_q, float))
    m = (from_resting_pose(config, plan) if from_rest else plan).moves[0]
    return move_duration_s(np.asarray(start_q, float), np.asarray(m.target_rad), m.speed_rad_s, m.accel_rad_s2)


def _one_run(config: Config, c: Candidate, noise: NoiseModel, theta: np.ndarray, check_safety: bool,
             start_q: Sequence[float] | None = None) -> tuple:
    """One run of the candidate: (robot s, noise covariance, the wrist term (``WristModel``), systematic covariance,
    samples, the safety gate's problems, the noise estimate's scatter (``noise_scatter``)), or (problems,) when it
    cannot be predicted; kept for the other repetition counts."""
    from payload_agent.errors import PayloadAgentError

    start = None if start_q is None else tuple(float(v) for v in start_q)
    key = (id(config), config.source, c, repr(noise), tuple(theta), check_safety, start)
    if key in _RUNS:
        return _RUNS[key]
    cfg = with_candidate(config, c)
    try:
        plan = plan_for(config, c)
        problems: tuple[str, ...] = ()
        if check_safety:
            from payload_agent.motion.safety import SafetyGate

            # the whole plan, exactly as ``plan`` and ``run`` check it before the first move (the approach too if known)
            begin = plan.moves[0].target_rad if start is None else start
            problems = tuple(SafetyGate(cfg).check(turned_to(cfg, plan, np.asarray(begin)),
                                                   np.asarray(begin)).problems)
        problems += too_few_samples(plan, noise.sample_period_s)
        shared = noise.shared_baseline is not None and noise.shared_baseline.reused_by(run_config(config, c))
        terms, n, wrist, spread = terms_and_wrist_model(cfg, plan, noise, theta, shared=shared, mount_rad=None if (
            start is None or not c.stored_baseline) else reusing_run_mount(cfg, plan, start))  # where it stands
        out: tuple = (robot_time_s(plan), terms["noise"], wrist, sum(terms[k] for k in SYSTEMATIC_TERMS), n, problems,
                      spread)
    except (PayloadAgentError, ValueError, np.linalg.LinAlgError) as exc:
        out = ((str(exc),),)
    if len(_RUNS) > 4096:
        _RUNS.clear()
    _RUNS[key] = out
    return out


@dataclass(frozen=True)
class Choice:
    best: Prediction | None  # None: no candidate meets the target
    table: list[Prediction]  # every candidate, fastest first

    def describe(self, mass_std_g: float, cog_std_mm: float, limit: int = 12) -> str:
        from payload_agent.output.plan_table import format_choice

        return format_choice(self, mass_std_g, cog_std_mm, TARGET_RISK, limit)


def choose(config: Config, mass_std_g: float, cog_std_mm: float, noise: NoiseModel, *,
           nominal_mass_kg: float = 2.0, nominal_cog_mm: Sequence[float] = (0.0, 0.0, 100.0),
           grid: Sequence[Candidate] | None = None, exhaustive: bool = False, after: int = 12,
           start_q: Sequence[float] | None = None, from_rest: bool = False) -> Choice:
    """The fastest candidate whose predicted σ meets the target (mass and every CoM axis, 1σ).

    The robot time of every candidate comes from its plan alone (cheap), so candidates are predicted
    (safety gate and σ) fastest first until one meets the target, and ``after`` more for the table;
    ``exhaustive`` predicts them all. ``start_q``: where the robot stands, so every robot time counts the
    approach move (which differs between procedures: their first poses differ); ``from_rest``: at travel speed.
    """
    theta = nominal_theta(nominal_mass_kg, nominal_cog_mm)

    def time_of(c: Candidate) -> float:
        from payload_agent.errors import PayloadAgentError

        try:
            return c.repetitions * robot_time_s(plan_for(config, c)) + approach_s(config, c, start_q, from_rest)
        except (PayloadAgentError, ValueError):
            return float("inf")  # predict() reports why

    ordered = sorted(grid or candidates_for(config), key=time_of)
    preds, found, extra = [], False, 0
    for c in ordered:
        p = predict(config, c, noise, theta, start_q=start_q, from_rest=from_rest)
        preds.append(p)
        found = found or p.meets(mass_std_g, cog_std_mm)
        extra += found and p.usable
        if found and extra > after and not exhaustive:
            break
    preds.sort(key=lambda p: (not p.usable, p.robot_time_s))
    ok = [p for p in preds if p.meets(mass_std_g, cog_std_mm)]
    return Choice(ok[0] if ok else None, preds)
