"""A tool cable as what it is, a spring on the wrist relaxed where the tool was mounted (issue 22).

A cable or hose from the forearm to the tool twists with the wrist: τ_j = κ_j·(q_j − rest_j) on wrist joint j,
κ_j ≥ 0 (a spring resists its deflection), rest_j the angle the joint stood at when the tool was mounted
(where the cable was fitted, relaxed; that is how the simulated cell's cable behaves, and an assumption for a
real one: docs/sources.md "Tool cable or hose"). The agent knows rest: the loaded run starts where the tool
went on (``Prepared.mount_rad``, the angles the loaded phase started from). During every arm sweep the
wrist stands still, so a joint's torque is one constant per pose, κ_j times a known lever q̄_j − rest_j:
three parameters for all poses together instead of the free offsets' one per (pose, wrist joint)
(``offsets.wrist_joint``), so the same torques are better determined. The spring is fitted beside θ and one
nuisance offset per moving arm joint (``moving_arm_joint``: the friction the two-direction average leaves there,
which otherwise reaches κ̂ through θ).

Presence: the likelihood-ratio statistic of κ = 0 against κ ≥ 0, T = κ*ᵀC⁻¹κ* with κ* the projection of
the fitted κ̂ (covariance C) onto κ ≥ 0 in C's metric. Under κ = 0 T is chi-bar-squared, a mixture of χ²_i
(i = 0..p) with weights set by C (docs/sources.md); its 1 − ``ALPHA`` quantile and its mean E₀[T] are
computed for this C by a fixed-seed draw. The term is the cable's effect on θ as measured, β̂ = A·M·κ* (M: the
levers): all of β̂β̂ᵀ where T exceeds the quantile (the cable is found), else w·β̂β̂ᵀ with w = (T − E₀[T])⁺/T, the
share the data show beyond noise (``shares``). The effect's own noise D = A·M·C·Mᵀ·Aᵀ is in no branch: the
reported θ̂ is the plain fit's, whose error is independent of κ̂, and E[β̂β̂ᵀ] = ββᵀ + D already holds one D
(``shares``). The weak cable of the benchmark (10–20 mN·m/rad) was found in 3 of 6 runs; the other 3 still erred
by 2–4 σ of mass the same way, which a term that is zero below the test leaves uncovered (docs/benchmarks.md,
session 12).

Where the robot YAML declares that a cable is fitted (``robot.tool_cable_fitted``), the test does not decide and the
cable's effect is taken out of θ̂ instead of being carried in σ (session 21). A spring that resists pushes θ̂ one
way in every run (+4.3 to +5.1 g of mass on the benchmark's realistic+cable arm, +5.5 of the hard arm's +7.4 g at
10 %; 23–24 of 24 cases positive), so a σ that holds ββᵀ covers a bias as if it were noise. The reported θ̂ is θ̂_plain
− A·M·κ̂ with κ̂ the unconstrained fit (``term``: ``Term.shift``), the posterior mean of κ under a flat prior on all
of κ (posterior N(κ̂, C)), and σ holds D = A·M·C·MᵀAᵀ. Its error is e + A·M·(κ − κ̂), e the plain fit's, independent
of κ̂ (``shares``: with the cable's and the arm joints' offset columns beside Y in one weighted fit, Cov(θ̂_plain,
κ̂) = 0), so its covariance is P + D whatever κ: the fit with the spring's columns fitted (Frisch–Waugh). The
physics' κ ≥ 0 is not used there: the posterior mean under a flat prior on κ ≥ 0 (κ̂'s normal truncated to the cone)
lies inside the cone whatever κ̂, so wherever σ_κ is of κ's size it over-corrects, by up to about σ_κ per joint: measured
−3.0 ± 0.9 g on hard 20 % and −2.7 ± 0.6 g on realistic+cable's default procedure (20 and 21 of 24 negative;
docs/benchmarks.md, session 21), against +2.2 ± 1.4 g and −1.1 ± 0.7 g for κ̂ (the hard arm's +1.9 g without its
cable is not the cable's). Not the default: on an arm without a cable the correction costs D (docs/benchmarks.md,
session 15 for the term before). D's drive-gain part is not independent of θ̂_plain's: a wrist drive's gain error
moves both, so σ holds the corrected estimate's response to each gain in place of the plain fit's
(``corrected_columns``, session 22). Not in C, measured (session 22, not modelled): the still wrist's
load-dependent gear ripple, a gain error per (pose, wrist joint) (``gain_scatter``), moves κ̂ by more than C at 1 %
sweeps on the hard arm.

Where the YAML declares that no cable or hose runs to the tool (``robot.tool_cable_fitted: false``), σ carries no
cable term below the test: the share w·β̂β̂ᵀ is there because the agent cannot tell a weak cable from noise, and the
user can (on the clean shipped sim-ec66 that share was in σ in 11 of 40 runs and widened the largest CoM σ by up to
0.45 mm, to at most 1.29 mm, with the same coverage without it: docs/benchmarks.md, session 26, "no tool cable"). Where the test still finds one (T above its 1 − ``ALPHA`` quantile, 5 % of
runs on an arm without a cable) the data contradict the declaration: σ holds the whole measured effect, as
undeclared, and the note names the key (``note``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation.systematics import gain_scatter, offsets, wrist
from payload_agent.evaluation.systematics.terms import Term
from payload_agent.solvers.fitted import ALL, FittedModel
from payload_agent.solvers.wls import Group, fit, gain_directions

ALPHA = 0.05  # false-alarm rate of the presence test on an arm without a cable
# a wrist joint that stands within this of where the tool was mounted in every pose feels no spring torque
MIN_LEVER_RAD = math.radians(1.0)
DRAWS = 4000  # draws of the chi-bar-squared null distribution (fixed seed: the same data give the same answer)


@dataclass(frozen=True)
class CableSpring:
    """The fitted spring: per wrist joint with a lever, its stiffness and the presence test."""

    joints: tuple[int, ...]  # 0-based wrist joints with a lever somewhere
    levers: np.ndarray  # (k, p): lever q̄ − rest (rad) of each (pose, wrist joint) offset label on each joint
    stiffness_nm_per_rad: np.ndarray  # (p,) κ*, projected onto κ ≥ 0
    cov: np.ndarray  # (p, p) covariance of the unconstrained κ̂
    statistic: float  # T
    critical: float  # the 1 − ALPHA quantile of T under κ = 0
    null_mean: float  # E[T] under κ = 0
    estimate: np.ndarray | None = None  # (p,) the unconstrained κ̂
    declared: bool = False  # ``robot.tool_cable_fitted: true``: κ̂'s effect comes off θ̂ (``term``)
    absent: bool = False  # ``robot.tool_cable_fitted: false``: no cable declared, no term unless the test finds one
    # {joint: (p,) σ_j·∂κ̂/∂ε_j}: κ̂'s response to each drive gain's standard uncertainty, the part of ``cov`` the
    # gains make (``cov`` = the noise's + Σ_j of their outer products); the same gain errors move θ̂_plain (``term``)
    gain_directions: dict[int, np.ndarray] | None = None

    @property
    def present(self) -> bool:
        return self.statistic > self.critical

    @property
    def weight(self) -> float:
        """The share of the measured effect β̂β̂ᵀ that goes into σ: all of it where the test finds a cable, else the
        share the data show beyond noise, (T − E₀[T])⁺/T (a cable too weak for the test still moves θ: 2–4 σ of mass
        in the weak-cable ablation's undetected cases). ``shares`` gives D no share. Declared: 1, the whole of κ̂'s
        effect, taken off θ̂ rather than put in σ (``term``). Declared absent (no cable or hose to the tool): 0 below
        the test, where the YAML says what the data cannot tell from noise; 1 above it, where the data contradict it."""
        if self.declared or self.present:
            return 1.0
        if self.absent:
            return 0.0
        return max(self.statistic - self.null_mean, 0.0) / self.statistic if self.statistic > 0 else 0.0


def levers(sweeps: Sequence[DeltaSweep], groups: Sequence[Group], labels: Sequence[str],
           mount_rad: Sequence[float]) -> tuple[np.ndarray, tuple[int, ...]]:
    """(M (k, p), joints): the lever q̄_j − rest_j of every (pose, wrist joint) label (q̄: the mean angle of the
    label's rows), one column per wrist joint whose lever exceeds ``MIN_LEVER_RAD`` somewhere."""
    by_name = {d.key.name: d for d in sweeps}
    sums: dict[str, list[float]] = {}
    for g in groups:
        d = by_name[g.sweep]
        name = offsets.wrist_joint(g, d)
        if name is not None:
            sums.setdefault(name, []).extend(np.asarray(d.q)[:, g.joint].tolist())
    rest = np.asarray(mount_rad, float)
    joint_of = {lab: int(lab.rsplit("/j", 1)[1]) - 1 for lab in labels}
    lever = {lab: float(np.mean(sums[lab])) - rest[joint_of[lab]] for lab in labels}
    joints = tuple(j for j in offsets.WRIST_JOINTS
                   if any(joint_of[lab] == j and abs(lever[lab]) > MIN_LEVER_RAD for lab in labels))
    M = np.zeros((len(labels), len(joints)))
    for i, lab in enumerate(labels):
        if joint_of[lab] in joints:
            M[i, joints.index(joint_of[lab])] = lever[lab]
    return M, joints


def _whitener(cov: np.ndarray) -> np.ndarray:
    """R with RᵀR = C⁻¹: R·κ̂ has unit covariance."""
    return np.linalg.cholesky(np.linalg.inv(cov)).T


def _projected(R: np.ndarray, u: np.ndarray) -> np.ndarray:
    from scipy.optimize import nnls

    return nnls(R, u)[0]


def project(kappa: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """κ*: the point of κ ≥ 0 nearest to ``kappa`` in the metric of C⁻¹ (non-negative least squares on the
    whitened problem ‖R(κ − κ̂)‖², RᵀR = C⁻¹)."""
    R = _whitener(cov)
    return _projected(R, R @ kappa)


def statistics(R: np.ndarray, U: np.ndarray) -> np.ndarray:
    """T of many whitened estimates at once (rows of ``U`` = R·κ̂, RᵀR = C⁻¹): the largest χ² drop ‖P_S·u‖² over
    the faces S of κ ≥ 0 (κ zero outside S) whose least-squares κ_S is feasible. The projection onto the cone
    lies on one such face, and every feasible κ_S is a point of the cone, so the largest feasible drop is
    the projection's (what ``project`` finds by non-negative least squares, one estimate at a time)."""
    from itertools import combinations

    p = R.shape[1]
    U = np.atleast_2d(U)
    best = np.zeros(len(U))
    for size in range(1, p + 1):
        for S in combinations(range(p), size):
            pinv = np.linalg.pinv(R[:, S])  # (|S|, p)
            k = U @ pinv.T
            drop = np.sum((k @ R[:, S].T) ** 2, axis=1)
            best = np.where(np.all(k >= 0.0, axis=1), np.maximum(best, drop), best)
    return best


def statistic(kappa: np.ndarray, cov: np.ndarray) -> float:
    """T = κ*ᵀC⁻¹κ*: the likelihood-ratio statistic of κ = 0 against κ ≥ 0 (for a projection onto a cone,
    κ̂ − κ* is orthogonal to κ* in C's metric, so T is the drop of the χ² from κ = 0 to κ*)."""
    R = _whitener(cov)
    return float(statistics(R, (R @ kappa)[None, :])[0])


def null_distribution(cov: np.ndarray, alpha: float = ALPHA, draws: int = DRAWS) -> tuple[float, float]:
    """(the 1 − α quantile, the mean) of T under κ = 0 (R·κ̂ standard normal): a chi-bar-squared whose weights
    depend on C's correlations; drawn with a fixed seed."""
    R = _whitener(cov)
    t = statistics(R, np.random.default_rng(20261127).standard_normal((draws, len(cov))))
    return float(np.quantile(t, 1.0 - alpha)), float(np.mean(t))


def moving_arm_joint(group: Group, sweep: DeltaSweep) -> str | None:
    """One nuisance offset per moving arm joint (1–3) over all its sweeps, fitted beside the spring: what the
    two-direction average leaves of that joint's friction, a direction asymmetry times the Coulomb level's change
    between the runs (``friction``), the same constant in every sweep of the joint. Without it that residual moved
    θ in the spring's fit, the wrist rows then disagreed with θ, and κ̂ took up the disagreement: 4–6 σ_κ low on
    the hard arm at 1 % sweeps (docs/benchmarks.md, session 17; session 18 for the fix)."""
    if group.joint == sweep.moving and group.joint not in offsets.WRIST_JOINTS:
        return f"moving/j{group.joint + 1}"
    return None


def fit_spring(model: FittedModel, labels: Sequence[str], mount_rad: Sequence[float],
               alpha: float = ALPHA, gain_reference: tuple | None = None, declared: bool = False,
               arm_offsets: offsets.Selector | None = moving_arm_joint, absent: bool = False) -> CableSpring | None:
    """The spring fitted beside θ on ``model``'s rows (with the still joints' nuisance gain columns where a
    torque-gain scatter is found, as ``wrist.measure`` does, and with what ``gain_reference``'s calibration
    absorbed of them on every row of their joints: ``wrist.columns``); None when no wrist joint has a lever.
    ``declared``: the robot YAML says a cable is fitted, so κ̂'s effect comes off θ̂ (``term``); ``absent``: it says
    none is (``robot.tool_cable_fitted: false``), so σ holds the effect only where the test finds one (``weight``).
    ``arm_offsets``: the nuisance offsets of the moving arm joints' rows fitted with it (``moving_arm_joint``; None:
    none, the fit before session 18)."""
    sweeps, groups = list(model.sweeps), list(model.groups)
    nuisance = gain_scatter.of_model(model).tau > 0
    aug, names = wrist.columns(sweeps, groups, model.fit(ALL).theta[:4], nuisance, gain_reference)
    if not names:
        return None
    M_all, joints = levers(sweeps, groups, names, mount_rad)
    if not joints:
        return None
    k = len(names)
    spring = [replace(g, Y=np.hstack([g.Y[:, :4], g.Y[:, 4:4 + k] @ M_all, g.Y[:, 4 + k:]])) for g in aug]
    if arm_offsets is not None:
        spring, _ = offsets.augment(sweeps, spring, arm_offsets)
    res = model.cached(("cable spring", tuple(np.round(np.asarray(mount_rad, float), 9)), nuisance,
                        gain_reference is not None and nuisance, getattr(arm_offsets, "__name__", None)),
                       lambda: fit(spring))
    p = len(joints)
    gains = {} if model.gain_rel_std is None else {
        j: d[4:4 + p] for j, d in gain_directions(spring, np.vstack([g.Y for g in spring]), res.weights,
                                                  res.normal_inverse, res.theta, model.gain_rel_std).items()}
    kappa = res.theta[4:4 + p]
    cov = res.cov[4:4 + p, 4:4 + p] + sum((np.outer(d, d) for d in gains.values()), np.zeros((p, p)))
    order = [names.index(lab) for lab in labels]
    return CableSpring(joints, M_all[order], project(kappa, cov), cov, statistic(kappa, cov),
                       *null_distribution(cov, alpha), kappa, declared, absent, gains)


def effect(spring: CableSpring, sens: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{fit: (4, 1 + p)}: the spring's measured effect A·M·κ* and its uncertainty A·M·chol(C) side by side
    (``sens``: {fit: (4, k)} of the offsets' labels): unit-σ columns whose sum of squares is β̂β̂ᵀ + D; where a
    cable is declared, A·M·κ̂ of the unconstrained κ̂ first. ``term`` weights them: undeclared, the run's σ takes
    the first column (``shares``: the uncertainty columns have share 0; they stay for what reads D); declared, θ̂
    loses the first and σ takes the others."""
    mean = spring.estimate if spring.declared else spring.stiffness_nm_per_rad
    L = np.linalg.cholesky(spring.cov)
    out = {}
    for which, A in sens.items():
        AM = A @ spring.levers
        out[which] = np.hstack([(AM @ mean)[:, None], AM @ L])
    return out


def shares(weight, found):
    """(a, b): the shares of the measured effect β̂β̂ᵀ and of its uncertainty D that a run puts into σ, a·β̂β̂ᵀ + b·D
    (numbers, or arrays of the plan's draws: ``planned_terms``) where the YAML declares no cable. a = 1 where the
    presence test finds a cable, else w = (T − E₀[T])⁺/T; b = 0 in both branches (declared: ``term``).

    Why no D: the estimate σ describes is the plain fit's (``Systematics.apply`` adds covariance and leaves θ̂ as
    fitted), and its error is e + β with e independent of β̂. With the cable columns Z beside Y,
    κ̂ = (ZᵀW·M_Y·Z)⁻¹ZᵀW·M_Y·y and M_Y·Y = 0, so with W the inverse noise covariance
    Cov(θ̂_plain, κ̂) = (YᵀWY)⁻¹Yᵀ·M_YᵀWZ(…) = 0 (docs/sources.md, Hausman). So D = Cov(β̂) is no part of the
    error, and β̂β̂ᵀ, whose mean is ββᵀ + D, already holds D once. β̂β̂ᵀ + D (the found branch until session 18) held
    it twice; w·D below the test likewise (session 17). D belongs in σ only where θ̂ is the fit with the spring
    fitted, θ̂_plain − A·M·κ̂, whose error is e + β − A·M·κ̂ (covariance P + D, no β̂β̂ᵀ): the declared branch
    (``term``). The arm joints' offsets and the gain nuisance columns beside the
    spring (``fit_spring``) are more columns of the same kind: the argument holds with M_Y for all of them."""
    w = np.asarray(weight, float)
    return w, np.zeros_like(w)


def plain_gain_directions(model: FittedModel, fits) -> dict[str, dict[int, np.ndarray]]:
    """{fit: {joint j: (4,) σ_j·∂θ̂/∂ε_j}}: each plain fit's response to each drive gain's standard uncertainty, the
    part of the estimate's covariance the gains make (``FittedModel.cov_params``, the quality gate's ``G``). A fit
    that is not the model's (the three-step solver's) gets zeros: its gain response is its own, which the
    correction does not reach, so the term gives it A·M·C·MᵀAᵀ as before."""
    out = {}
    for which in (ALL, *(f for f in fits if f in model.poses)):
        res, groups = model.fit(which), list(model.groups_of(which))
        out[which] = {j: d[:4] for j, d in gain_directions(groups, np.vstack([g.Y for g in groups]), res.weights,
                                                           res.normal_inverse, res.theta,
                                                           model.gain_rel_std).items()}
    return {which: out.get(which, {j: np.zeros(4) for j in out[ALL]}) for which in fits}


def corrected_columns(AM: np.ndarray, C_noise: np.ndarray, kappa_gains: Sequence[np.ndarray],
                      plain_gains: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """((4, p + 2·J) columns, signs): what a declared cable's correction θ̂_plain − AM·κ̂ adds to the plain fit's
    covariance: κ̂'s noise AM·chol(C_noise) (sign +), and per drive gain j the corrected θ̂'s response
    u_j = a_j − AM·k_j (+) beside the plain fit's a_j (−), which the estimate's covariance already holds (k_j, a_j:
    κ̂'s and θ̂_plain's response to one standard uncertainty of gain j).

    Why: a gain error of a wrist joint scales that joint's payload torque, which moves θ̂_plain and κ̂ together, so
    the corrected θ̂ moves by their difference; taking a_ja_jᵀ and AM·k_jk_jᵀ·AMᵀ as independent gave 0.53 × that
    variance where the two move θ̂ the same way (tests/test_cable_spring.py) and 4 × where they cancel
    (docs/benchmarks.md, session 22). The noise part is independent of θ̂_plain's (``shares``; under the run's
    noise maps the cross term is 0–6 % of σ, session 22)."""
    a = np.column_stack(plain_gains) if len(plain_gains) else np.zeros((4, 0))
    k = AM @ np.column_stack(kappa_gains) if len(kappa_gains) else np.zeros((4, 0))
    lam, vec = np.linalg.eigh(0.5 * (C_noise + C_noise.T))  # a square root that rounding cannot make fail
    return (np.hstack([AM @ (vec * np.sqrt(np.maximum(lam, 0.0))), a - k, a]),
            np.r_[np.ones(len(C_noise) + a.shape[1]), -np.ones(a.shape[1])])


def declared_columns(spring: CableSpring, sens: dict[str, np.ndarray],
                     plain_gains: dict[str, dict[int, np.ndarray]]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """({fit: (4, 1 + p + 2·J)}, signs): a declared cable's shift A·M·κ̂ (σ 0) and ``corrected_columns`` for each
    fit, over the drive gains both the spring fit and every plain fit respond to."""
    p = len(spring.joints)
    gains = sorted(set(spring.gain_directions or {}) & set.intersection(*(set(g) for g in plain_gains.values())))
    k = [spring.gain_directions[j] for j in gains]
    C_noise = spring.cov - sum((np.outer(v, v) for v in k), np.zeros((p, p)))
    out = {}
    for which, A in sens.items():
        AM = A @ spring.levers
        cols, sign = corrected_columns(AM, C_noise, k, [plain_gains[which][j] for j in gains])
        out[which] = np.hstack([(AM @ spring.estimate)[:, None], cols])
    return out, np.r_[1.0, sign]


def term(spring: CableSpring, sens: dict[str, np.ndarray], model: FittedModel | None = None) -> Term | None:
    """The run's tool-cable term (``systematics.wrist_terms``). Declared: θ̂ of every fit loses κ̂'s effect A·M·κ̂
    (``Term.shift``) and σ holds the corrected θ̂'s part beyond the plain fit's: κ̂'s noise A·M·C_noise·MᵀAᵀ and
    the drive gains' response replaced by the corrected fit's (``declared_columns``; without ``model``, whose
    plain fits' gain responses that needs: D = A·M·C·MᵀAᵀ). Else a·β̂β̂ᵀ in σ (``shares``); None where that share
    is 0: below the test where the YAML declares no cable (``CableSpring.absent``), whose note names the key where the
    test contradicts it."""
    p = len(spring.joints)
    if spring.declared:
        if model is not None and model.gain_rel_std is not None and spring.gain_directions:
            cols, sign = declared_columns(spring, sens, plain_gain_directions(model, sens))
        else:
            cols, sign = effect(spring, sens), None
        return Term("tool cable", np.r_[0.0, np.ones(cols[ALL].shape[1] - 1)], cols, note(spring, cols[ALL][0, 0]),
                    {which: c[:, 0] for which, c in cols.items()}, sign)
    cols = effect(spring, sens)
    if spring.weight <= 0:
        return None
    a, b = shares(spring.weight, spring.present)
    return Term("tool cable", np.r_[np.sqrt(a), np.full(p, np.sqrt(b))], cols, note(spring))


def note(spring: CableSpring, mass_shift_kg: float = 0.0) -> str:
    """The result's note on the cable term, in the words of the branch that made it (``term``, ``shares``)."""
    stiff = ", ".join(f"j{j + 1} {1000 * k:.0f}" for j, k in zip(spring.joints, spring.stiffness_nm_per_rad))
    test = f"test statistic {spring.statistic:.1f} {'>' if spring.present else '≤'} {spring.critical:.1f}"
    if spring.declared:
        fitted = ", ".join(f"j{j + 1} {1000 * k:+.0f}±{1000 * math.sqrt(v):.0f}"
                           for j, k, v in zip(spring.joints, spring.estimate, np.diag(spring.cov)))
        return (f"a tool cable on the wrist, declared fitted (robot.tool_cable_fitted; a spring relaxed where the "
                f"tool was mounted, {test}): its effect removed from the result at the stiffness's posterior mean "
                f"under a flat prior on κ, not restricted to κ ≥ 0 (the spring fitted beside θ: {fitted} mN·m/rad; "
                f"the mass {-1000 * mass_shift_kg:+.1f} g by it), that estimate's noise in σ")
    if spring.present and spring.absent:
        return (f"a tool cable on the wrist although the robot YAML declares none (robot.tool_cable_fitted: false): "
                f"the data show a spring relaxed where the tool was mounted, {stiff} mN·m/rad ({test}; on an arm "
                f"without one this happens in {100 * ALPHA:.0f} % of runs); its effect on the result as measured, in "
                "σ. If a cable or hose runs to the tool, set robot.tool_cable_fitted: true (its effect is then taken "
                "off the result); if none does, this run is one of those chance findings")
    if spring.present:
        return (f"a tool cable on the wrist (a spring relaxed where the tool was mounted, {stiff} mN·m/rad; found: "
                f"{test}): its effect on the result as measured, in σ")
    return (f"a tool cable on the wrist (a spring relaxed where the tool was mounted, {stiff} mN·m/rad; not "
            f"significant, {test}): its effect on the result as measured, {spring.weight:.2f} × of it (the share "
            "the data show beyond noise), in σ")


__all__ = ["term", "corrected_columns", "declared_columns", "plain_gain_directions", "note", "shares", "ALPHA",
           "CableSpring", "levers", "moving_arm_joint", "project", "statistics", "statistic", "null_distribution",
           "fit_spring", "effect"]
