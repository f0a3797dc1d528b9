"""The one recipe for a real arm's systematic errors: compensate what is declared, put the rest into σ.

Every systematic-error term lives in this package (issue 22 reworks them here): this module is the recipe
and ``TERMS``; ``compliance`` the joint stiffness and zeros (compensation, finite-difference sensitivities),
``offsets`` the torques the model lacks (friction gaps, nuisance-offset fits, wrist torques),
``gain_scatter`` the torque-gain scatter between standing angles, ``terms`` the Term and Systematics types. Every
term is evaluated on the analysis' one fitted model (``solvers.fitted``).

A real arm has errors no amount of averaging removes, the same on every sample of a run. This
module is what ``payload-agent run`` / ``solve`` (``evaluation.analyse``), ``calibrate``
(``calibration.fit_gains``) and the accuracy benchmark (method general-bi-cal-comp) all do about them:

1. ``prepare``: the declared joint stiffness (``robot.kinematics.stiffness_nm_per_rad``) is
   compensated in the loaded and the empty run alike (``systematics.compliance.compensate``: every
   sample moved to its link angle q − τ/k) before the baseline subtraction and the combination
   of the two directions;
2. ``evaluate``: every entry of ``TERMS`` turns what is known about one error source into a
   ``Term``: its parameters' standard deviations and θ's first-order response to each, for the
   combined fit (``ALL``) and for each pose's own fit (so the quality gate's pose-agreement check
   counts exactly the part that moves the poses apart):
   - stiffness: the declared stiffness' relative uncertainty (``stiffness_uncertainty_percent``),
     per joint, by finite differences of the whole analysis (``compliance.sensitivities``);
   - joint zeros: ``zero_offset_uncertainty_deg`` per joint, likewise;
   - residual friction: the two-direction average cancels friction odd in speed; a Coulomb
     direction asymmetry a_j leaves a_j·s·C_j even in speed, which cancels against the baseline only if
     the friction level s did not change. The change of the part the asymmetry acts on is MEASURED per
     joint (``systematics.friction``: along each sweep's whole legs, ramps included, the legs' half gap is
     split into a Coulomb part, a viscous part growing with speed and a part growing with the load torque;
     the Coulomb part's change between the empty and the loaded run, pooled over the joint's sweeps; the
     constant part at the sweep speed, viscous included as a margin, where the legs' speeds cannot split
     it). The net change of the whole gap is no measure of it: the tool's load raises the load-dependent
     part, which is symmetric and cancels, and can hide a Coulomb drop. Where the sweeps' load torque varies too little to split
     the two, the declared change (``robot.friction_change_percent`` of the baseline's level) is the
     prior the measurement is combined with. The residual a_j·Δ_j itself is MEASURED (session 19): one offset per
     moving joint beside θ (``residual_friction``), the declared asymmetry × the measured change its prior;
   - torque-gain scatter: a still joint's measured payload torque off by a relative error that differs
     from one standing angle to the next (gear ripple growing with load): its effect on θ, less what a
     drive-gain calibration at the same angles absorbed (``gain_reference``), each cluster's error as the
     data tell it given the scatter's size (posterior mean and covariance, ``systematics.gain_scatter``);
   - tool cable / wrist torques: where the loaded run's start is known, a spring on the wrist relaxed there,
     tested and, when present, its measured effect on θ in σ (``cable_spring``; where ``robot.tool_cable_fitted``
     declares one, the fitted spring's effect taken off θ̂ and that estimate's noise in σ);
     else one constant per (pose, wrist joint) beside a nuisance gain column per still (joint, angle) of
     joints 1–3, their measured effect shrunk likewise (``systematics.wrist``); a strong one fails the
     gate's cable check instead;
3. ``Systematics.apply``: the general solver's estimate with Σ_terms A·diag(σ²)·Aᵀ added and a note
   per term; ``quality.evaluate(systematics=...)`` adds the same terms to the pose comparison. The
   three-step solver's estimate gets the same terms through its own sensitivities (``THREE_STEP``, by
   finite differences of its inputs: ``systematics.three_step_response``).

To add an error source, append a function ``(Context) -> list[Term]`` to ``TERMS``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from payload_agent.analysis.combine import add_combined
from payload_agent.analysis.delta import DeltaSweep, subtract_all
from payload_agent.configuration.config import JointSystematicsConfig
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.recording.rundata import SweepData
from payload_agent.evaluation import calibration_clusters, reference_shares
from payload_agent.evaluation.systematics import (cable_spring, compliance, friction, gain_scatter, offsets,
                                                  reference_friction, residual_friction, three_step_response,
                                                  three_step_rows, three_step_scatter, wrist)
from payload_agent.evaluation.systematics.planned import planned_covariance
from payload_agent.evaluation.systematics.terms import Systematics, Term
from payload_agent.evaluation.systematics.three_step_response import THREE_STEP
from payload_agent.solvers import general, wls
from payload_agent.solvers.fitted import ALL, FittedModel  # ALL: the combined fit's key (others: poses)
from payload_agent.types import SweepKey

RIGID = JointSystematicsConfig(None, 0.0, (0.0,) * 6, 0.0, 0.0)  # nothing declared: no compensation, no term

Sweeps = Mapping[SweepKey, SweepData]
Deltas = dict[SweepKey, DeltaSweep]
GainReference = tuple  # (θ_ref, fitted joints[, standing angles]) of a drive-gain calibration (GainCalibration.reference)


def joint_declaration(decl: JointSystematicsConfig) -> compliance.JointSystematics:
    return compliance.JointSystematics(decl.stiffness_nm_per_rad, decl.stiffness_rel_std, decl.zero_offset_std_rad,
                                       decl.zero_gain_coupling)


def deltas_of(loaded: Sweeps, empty: Sweeps, commands: Mapping | None = None,
              notes: list[str] | None = None) -> Deltas:
    """Loaded minus empty, and the friction-cancelling combination of the two directions."""
    deltas, problems = add_combined(subtract_all(dict(loaded), dict(empty), commands))
    if notes is not None:
        notes.extend(problems)
    return deltas


@dataclass
class Prepared:
    """A run's sweeps as the analysis sees them: raw, compensated, and their deltas."""

    raw_loaded: Sweeps
    raw_empty: Sweeps
    loaded: dict[SweepKey, SweepData]  # compensated
    empty: dict[SweepKey, SweepData]
    deltas: Deltas  # of the compensated sweeps, combined where both directions were recorded
    commands: Mapping | None = None
    notes: list[str] = field(default_factory=list)
    # the joint angles (rad, as reported) the loaded run started from, where the tool was mounted: the rest
    # angles of a tool cable's spring (``cable_spring``); None: not recorded (the free wrist offsets then)
    mount_rad: np.ndarray | None = None
    # (sweep name, still joint) -> the calibration's (ε̂, σ_ε) whose 1 + ε̂ divided those rows (``calibration_clusters``)
    still_scales: Mapping[tuple[str, int], tuple[float, float]] = field(default_factory=dict)


def prepare(loaded: Sweeps, empty: Sweeps, decl: JointSystematicsConfig, commands: Mapping | None = None,
            mount_rad: Sequence[float] | None = None, gain_reference: GainReference | None = None) -> Prepared:
    """Step 1: compensate the declared stiffness in both runs, subtract, combine (``mount_rad``: where the loaded run
    started, for the cable term); the calibration's per-angle gain errors off the rows standing at its angles."""
    c = joint_declaration(decl).compliance()
    lo, em = compliance.compensate(loaded, c), compliance.compensate(empty, c)
    notes: list[str] = []
    deltas, stood = calibration_clusters.corrected(deltas_of(lo, em, commands, notes), gain_reference)
    notes += [calibration_clusters.note(stood)] if stood else []
    mount = None if mount_rad is None else np.asarray(mount_rad, float)
    return Prepared(loaded, empty, lo, em, deltas, commands, notes, mount, stood)


# -- the fits every term is evaluated on ------------------------------------------------------------------

@dataclass
class Context:
    """What the terms need: the prepared run, the model, the declaration and the base fits."""

    prepared: Prepared
    kin: Kinematics
    decl: JointSystematicsConfig
    gain_rel_std: Sequence[float] | None
    sweeps: list[DeltaSweep]
    groups: dict[str, list[wls.Group]]  # ALL and each pose
    fits: dict[str, wls.FitResult]

    model: FittedModel | None = None
    three_step: np.ndarray | None = None  # the three-step solver's θ on the same deltas (None: not solvable)
    gain_reference: GainReference | None = None  # (θ_ref, fitted joints) of the drive-gain calibration, if any

    @classmethod
    def build(cls, prepared: Prepared, kin: Kinematics, decl: JointSystematicsConfig,
              gain_rel_std: Sequence[float] | None = None, model: FittedModel | None = None,
              gain_reference: GainReference | None = None) -> "Context":
        """The context on ``model`` (the analysis' fitted model of ``prepared.deltas``; made here if None)."""
        if model is None:
            model = general.fit_model(prepared.deltas, kin, gain_rel_std)
        fits = model.fits()  # a pose that cannot be solved alone is left out: the gate says so
        if ALL not in fits:
            raise DataError("systematics: the combined fit is impossible")
        groups = {which: model.groups_of(which) for which in (ALL, *model.poses)}
        return cls(prepared, kin, decl, gain_rel_std, list(model.sweeps), groups, fits, model,
                   three_step_response.theta(prepared.deltas, kin), gain_reference)

    def thetas(self, deltas: Deltas) -> np.ndarray:
        """θ of every base fit (ALL, then the poses) on other deltas, with the base fits' weights, then the
        three-step solver's θ if it solved the run: (4·F [+ 4],)."""
        sweeps = general.select_sweeps(deltas)
        pose_of = {d.key.name: d.key.pose for d in sweeps}
        groups = general.build_groups(sweeps, self.kin)
        out = []
        for which, base in self.fits.items():
            gs = [g for g in groups if which == ALL or pose_of[g.sweep] == which]
            sigma = base.sigma_nm
            w = np.concatenate([np.full(len(g.y), 1.0 / max(sigma.get(g.label, wls.SIGMA_FLOOR_NM), 1e-12) ** 2)
                                for g in gs])
            theta, _ = wls.weighted_lstsq(np.vstack([g.Y for g in gs]), np.concatenate([g.y for g in gs]), w)
            out.append(theta)
        if self.three_step is not None:  # NaN where it cannot solve the shifted sweeps: no three-step response then
            th = three_step_response.theta(deltas, self.kin)
            out.append(np.full(4, np.nan) if th is None else th)
        return np.concatenate(out)

    def split(self, d: np.ndarray) -> dict[str, np.ndarray]:
        """(P, 4·F [+ 4]) finite-difference rows -> {fit (and THREE_STEP): (4, P)}."""
        out = {which: d[:, 4 * i:4 * i + 4].T for i, which in enumerate(self.fits)}
        if self.three_step is not None:
            block = d[:, 4 * len(self.fits):4 * len(self.fits) + 4].T
            if np.all(np.isfinite(block)):
                out[THREE_STEP] = block
        return out

    def offset_sens(self, selector: offsets.Selector, labels: Sequence[str]) -> dict[str, np.ndarray]:
        """{fit: (4, P)} of constant torques on the rows ``selector`` names ``labels[p]``."""
        out = {}
        for which, res in self.fits.items():
            s = offsets.offset_sensitivities(self.sweeps, self.groups[which], res.weights, res.normal_inverse,
                                             selector)
            out[which] = np.column_stack([s.get(lab, np.zeros(4)) for lab in labels]) if labels else np.zeros((4, 0))
        if self.three_step is not None:
            try:  # not solvable with a step added: no three-step response (its estimate says so)
                out[THREE_STEP] = three_step_response.offset_response(self.prepared.deltas, self.kin, self.sweeps,
                                                                       self.groups[ALL], selector, labels,
                                                                       self.three_step)
            except DataError:
                pass
        return out


# -- the terms ----------------------------------------------------------------------------------------------

def joint_terms(ctx: Context) -> list[Term]:
    """Declared stiffness and zero-offset uncertainties, by finite differences of the whole analysis."""
    jd = joint_declaration(ctx.decl)
    c, zstd = jd.compliance(), jd.zero_std()
    s_c = np.where(c > 0, jd.stiffness_rel_std, 0.0)
    if not s_c.any() and not zstd.any():
        return []
    p = ctx.prepared

    def theta_of(lo, em):  # corrected as the run's deltas were
        return ctx.thetas(calibration_clusters.scaled(deltas_of(lo, em, p.commands), p.still_scales))

    d_c, d_z = compliance.sensitivities(p.raw_loaded, p.raw_empty, jd, theta_of)
    out = []
    if s_c.any():
        k = jd.stiffness_nm_per_rad or ()
        out.append(Term("joint stiffness", s_c, ctx.split(d_c),
                        "joint elasticity compensated (k = " + "/".join(f"{v:.3g}" for v in k) + " N·m/rad), "
                        f"its ±{100 * jd.stiffness_rel_std:.0f} % uncertainty in σ"))
    if zstd.any():
        if ctx.decl.zero_offset_corr is None:
            out.append(Term("joint zeros", zstd, ctx.split(d_z),
                            f"joint zero uncertainty {np.degrees(zstd.max()):.3g}° in σ"))
        else:  # measured jointly by a calibration: the whole covariance, as independent principal parameters
            js = np.flatnonzero(zstd > 0)
            V, s = compliance.principal(compliance.zero_covariance(zstd, ctx.decl.zero_offset_corr), js)
            out.append(Term("joint zeros", s, {k: A[:, js] @ V for k, A in ctx.split(d_z).items()},
                            "joint zero uncertainty " + ", ".join(f"j{j + 1} {np.degrees(zstd[j]):.3g}°" for j in js)
                            + " in σ (correlated as the calibration measured them)"))
    return out


def friction_terms(ctx: Context) -> list[Term]:
    """What a Coulomb direction asymmetry leaves of the friction in the two-direction average: measured as one
    offset per moving joint beside the fit (``residual_friction``), with the declared asymmetry × the change of the
    Coulomb part between the runs (measured per joint from the legs' gaps, ``systematics.friction``; the declared
    change its prior) as the prior."""
    asym = float(ctx.decl.friction_asymmetry_std)
    if asym <= 0:
        return []
    p = ctx.prepared
    loaded, empty = friction.friction_gaps(p.loaded, p.commands), friction.friction_gaps(p.empty, p.commands)
    pairs = sorted({(d.key.pose, d.moving) for d in ctx.sweeps if d.key.direction == "both"}
                   & set(loaded) & set(empty))
    if not pairs:
        return []
    rel = float(ctx.decl.friction_change_std)
    joints = sorted({j for _, j in pairs})
    change, constant = {}, {}
    for j in joints:
        mine = [pj for pj in pairs if pj[1] == j]
        level = max(abs(empty[pj].level_nm) for pj in mine)  # the baseline's friction level: the prior's scale
        change[j] = friction.coulomb_change([loaded[pj] for pj in mine], [empty[pj] for pj in mine], rel * level, rel)
        constant[j] = friction.constant_level([empty[pj] for pj in mine])  # what the asymmetry multiplies

    tool_joints = set(joints)

    def per_joint(g: wls.Group, d: DeltaSweep) -> str | None:
        ok = g.joint == d.moving and d.key.direction == "both" and g.joint in tool_joints
        return str(g.joint) if ok else None

    ref, all_joints = "", list(joints)
    if ctx.gain_reference is not None:  # the same asymmetry in the calibration's reference run, read through the
        # gains: its change as the calibration measured it, else the declared change of the baseline's constant part;
        # a joint only the calibration swept both ways gets its reference column too (no tool-run leftover there)
        stored = reference_shares.of_reference(ctx.gain_reference)
        measured_ref = reference_friction.of_reference(ctx.gain_reference)
        extra = [] if stored is None or measured_ref is None else [
            k for k in stored.friction_joints() if k not in tool_joints and measured_ref.of_joint(k) is not None]
        all_joints = sorted([*joints, *extra])
        for k in extra:
            change[k], constant[k] = friction.CoulombChange(0.0, float("inf"), 0.0, 0.0, 0.0, True), 0.0
    labels = [str(j) for j in all_joints]
    sens, offs, gains = ctx.offset_sens(per_joint, labels), residual_friction.measure(ctx.model, ctx.gain_reference), None
    mu_r = sd_r = np.zeros(len(all_joints))
    if ctx.gain_reference is not None:
        eps = three_step_response.reference_offset_shares(ctx.sweeps, ctx.groups[ALL], per_joint, labels,
                                                          ctx.gain_reference, all_joints)
        calib = reference_friction.reference_columns(ctx.prepared.deltas, ctx.kin, ctx.sweeps, ctx.groups[ALL],
                                                     per_joint, labels, ctx.gain_reference, ctx.fits[ALL],
                                                     ctx.three_step, sens, all_joints, eps)
        mu_r, sd_r, ref = reference_friction.reference_change(ctx.gain_reference, all_joints, rel, constant)
        gains = residual_friction.through_gains(ctx.model, eps, mu_r, sd_r, ctx.gain_reference)
        how_ref = ("the calibration's own fit of its sweeps (gains.json)" if stored is not None
                   else reference_shares.STAND_IN_NOTE)
        ref = f"; also in the drive-gain calibration's reference run, {ref}, read through its gains by {how_ref}"
    else:
        calib = {which: np.hstack([S, np.zeros_like(S)]) for which, S in sens.items()}
    post = residual_friction.posterior(asym, [change[j] for j in all_joints], all_joints, offs, gains)
    std, sens = residual_friction.columns(post, calib, mu_r, sd_r)
    measured = [f"j{j + 1} {change[j].measured_nm:+.3f}±{change[j].measured_std_nm:.3f}"
                + ("" if change[j].coulomb_only else " with the viscous part at the sweep speed")
                for j in joints if change[j].measured]
    prior = [f"j{j + 1}" for j in joints if not change[j].measured]
    how = ("measured " + ", ".join(measured) + " N·m") if measured else ""
    if prior:
        how += ("; " if how else "") + (f"declared ±{100 * rel:.3g} % of the baseline's level where the sweeps' load "
                                        f"torque varies too little to tell ({', '.join(prior)})")
    return [Term("residual friction", std, sens,
                 f"friction direction asymmetry × the change of the Coulomb friction part between the runs ({how}): "
                 f"{residual_friction.describe(post, asym)}{ref} in σ"), *three_step_rows.terms(post, calib)]


def wrist_terms(ctx: Context) -> list[Term]:
    """Torques on the still wrist the model lacks (a tool cable). Where the loaded run's start (where the tool
    was mounted) is known: a spring relaxed there, its presence tested and, when present, its measured effect
    on θ and that effect's uncertainty (``systematics.cable_spring``). Else one free offset per (pose, wrist
    joint), their effect on θ shrunk to what the data show beyond noise (``systematics.wrist``)."""
    by_name = {d.key.name: d for d in ctx.sweeps}
    labels = sorted({offsets.wrist_joint(g, by_name[g.sweep]) for g in ctx.groups[ALL]} - {None})
    if not labels:
        return []
    sens = ctx.offset_sens(offsets.wrist_joint, labels)
    if ctx.prepared.mount_rad is not None:
        return _spring_terms(ctx, labels, sens)
    try:
        w = wrist.measure(ctx.model, sens[ALL], labels)
    except (DataError, np.linalg.LinAlgError):
        return []
    if w is None or w.shrink <= 0:
        return []
    return [Term("wrist torques", np.array([w.shrink]), wrist.along(w.offsets_nm, sens),
                 f"constant wrist torques (up to {1000 * float(np.max(np.abs(w.offsets_nm))):.0f} mN·m, from the data; "
                 f"their effect on the result {w.shrink:.2f} × as measured, q = {w.q:.1f}) in σ")]


def _spring_terms(ctx: Context, labels: list[str], sens: dict[str, np.ndarray]) -> list[Term]:
    try:
        s = cable_spring.fit_spring(ctx.model, labels, ctx.prepared.mount_rad, gain_reference=ctx.gain_reference,
                                    declared=ctx.decl.tool_cable_fitted is True, absent=ctx.decl.tool_cable_absent)
    except (DataError, np.linalg.LinAlgError):
        return []
    t = None if s is None else cable_spring.term(s, sens, ctx.model)  # declared: the fitted κ̂'s effect off θ̂
    return [] if t is None else [t]


def gain_scatter_terms(ctx: Context) -> list[Term]:
    """Torque-gain errors that differ between the angles still joints stand at (gear ripple under load): their
    effect on θ, less what a drive-gain calibration absorbed, from each cluster's posterior given the measured
    scatter (``systematics.gain_scatter``; the still wrist's clusters, measured worse than the scatter, at its size).
    The three-step solver's columns are its own (``systematics.three_step_scatter``), zero in the general fits'."""
    out = gain_scatter.term(ctx.prepared.deltas, ctx.kin, ctx.gain_rel_std,
                            {w: (ctx.groups[w], f) for w, f in ctx.fits.items()}, ALL, ctx.model, ctx.gain_reference)
    three = None  # the three-step reads no still row, only the calibrated gains of joints 2 and 3: its own
    if ctx.three_step is not None and ctx.model is not None:  # measurement of the clusters carried there
        try:
            three = three_step_scatter.effect(ctx.prepared.deltas, ctx.kin, ctx.model, ctx.gain_reference,
                                              ctx.three_step)
        except DataError:  # not solvable with a gain step: no three-step response (its estimate says so)
            pass
    parts, notes = [], []
    if out is not None:
        cols = out.effect_columns()
        parts.append({which: A @ cols for which, A in out.sens.items()})
        notes.append(out.note + ", each cluster's error as measured where the data tell it better than the "
                     "scatter, the scatter's size where they do not")
    if three is not None:
        parts.append({THREE_STEP: three.along})
        notes.append(three.note)
    if not parts:
        return []
    keys = [*ctx.fits, *([THREE_STEP] if ctx.three_step is not None else [])]
    along = {k: np.hstack([p.get(k, np.zeros((4, next(iter(p.values())).shape[1]))) for p in parts]) for k in keys}
    return [Term("torque-gain scatter", np.ones(along[ALL].shape[1]), along, "; ".join(notes))]


TERMS: list[Callable[[Context], list[Term]]] = [joint_terms, friction_terms, wrist_terms, gain_scatter_terms]


def evaluate(prepared: Prepared, kin: Kinematics, decl: JointSystematicsConfig,
             gain_rel_std: Sequence[float] | None = None,
             terms: Sequence[Callable[[Context], list[Term]]] | None = None,
             model: FittedModel | None = None, gain_reference: GainReference | None = None) -> Systematics:
    """Step 2: every term of ``TERMS`` on a prepared run (``gain_rel_std`` as the estimate was solved with;
    ``model``: the analysis' fitted model of ``prepared.deltas``, made here if None; ``gain_reference``: the
    drive-gain calibration the data were scaled with, (θ_ref, fitted joints), None for nominal gains)."""
    out = Systematics()
    try:
        ctx = Context.build(prepared, kin, decl, gain_rel_std, model, gain_reference)
    except (DataError, np.linalg.LinAlgError) as exc:
        out.notes.append(f"systematic error terms not evaluated: {exc}")
        return out
    for make in (TERMS if terms is None else terms):
        try:
            out.terms.extend(make(ctx))
        except (DataError, np.linalg.LinAlgError) as exc:
            out.notes.append(f"{make.__name__.replace('_', ' ')} not evaluated: {exc}")
    return out


__all__ = ["ALL", "THREE_STEP", "RIGID", "Prepared", "Term", "Systematics", "Context", "TERMS", "prepare", "evaluate",
           "deltas_of", "joint_terms", "friction_terms", "wrist_terms", "gain_scatter_terms", "planned_covariance"]
