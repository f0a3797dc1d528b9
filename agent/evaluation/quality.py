"""Quality gates: redundant checks on an identification, and their enforcement.

``evaluate`` computes every check on the baseline-subtracted sweeps (the data-level checks use
the general weighted fit, which has residuals and a covariance, whatever the primary solver;
the primary's own estimate is checked too);
``require_passed`` raises QualityGateError listing every failed check with its numbers.
The runner calls it before anything is written to a controller and for the exit code.

Each check is ``{"check": name, "value": v, "limit": l, "passed": bool, ...}``. Limits are
set so that simulated runs with realistic noise, friction drift, load-dependent friction and
DH lengths off by up to 0.5 mm pass after a drive-gain calibration (benchmarks/accuracy.py,
"gate pass" column; docs/benchmarks.md), while a grossly wrong drive gain (≥ 10 % on one
joint), a missing tool, or disagreeing poses fail. With uncalibrated gains off by ±3 % the
drive-gain check passes, but the poses often disagree by more than their uncertainty (which
cannot include an unknown gain error): calibrate.

- pose agreement: poses b and d each determine mass and all three centre-of-mass components
  on their own (joints 2–3 see the lever along the arm, the wrist joints the rest); the two
  estimates must agree within the uncertainty of their difference. That uncertainty has the
  same terms as the primary estimate's (``general.solve``): the sensor noise, independent
  between the poses (different sweeps), plus — when the caller passes them, as
  ``evaluation.analyse`` does — the drive-gain uncertainty of a calibration and the DH lengths'
  standard uncertainty. Those two are common to both poses (one drive, one arm), so they are
  not added in quadrature: the same gain error ε_j and the same length error δp_k are
  propagated through both per-pose fits (first order, as in ``wls.gain_covariance`` and
  ``general.kinematic_sensitivities``, the calibration's absorption of length errors included)
  and only the part that moves the two estimates differently enters the difference's covariance.
  The systematic terms of a real arm (``evaluation.systematics``: joint stiffness and zeros,
  residual friction, wrist torques), when the caller passes them, enter the same way: each term
  holds every pose's own response to its parameters. Every pair of poses is compared (mass and three
  centre-of-mass axes: 4 tests a pair). The limits, 3 σ (mass) and 3.5 σ (per axis), are the paper's two-pose
  procedure's: a false-refusal rate of 0.41 % per run if the z's are N(0, 1). With more poses (j2_triple:
  3 pairs, 12 tests) they are raised by Šidák (``pose_agreement_limits``) so that all pairs together keep
  that 0.41 % (3.32 σ / 3.78 σ for three pairs; benchmarks/pose_agreement.py measures it, docs/analysis.md);
- conditioning of the combined fit;
- mass positive, clearly above its own uncertainty (a tool is mounted) and below a sane bound;
- enough constant-speed samples in every sweep;
- residual RMS of every (sweep, joint) no more than a few times the sensor noise, estimated
  from the same data (second differences), so nothing is assumed about the robot;
- drive-gain consistency: with θ fitted on all joints, each well-loaded joint's measured
  torque must match the model to within a few per cent (a larger mismatch is a wrong drive
  gain, which no other check sees because it scales both poses alike);
- tool cable (``cable_check``): a constant torque on the still wrist that the payload's weight does
  not explain and that moves the result, named as the likely cause;
- the primary estimate itself, whichever solver made it (``solver_checks``): it reports an
  uncertainty; a primary other than the general fit passes its own mass checks; and it agrees
  with the other solvers' estimates on the same data within their uncertainty (the general and
  the three-step solver check each other).
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError, QualityGateError
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import SweepKey
from payload_agent.solvers.results import Estimate, RunResult
from payload_agent.solvers import general, length_response, wls
from payload_agent.solvers.fitted import ALL, FittedModel
from payload_agent.evaluation import cable_check
from payload_agent.evaluation.solver_checks import make_check as _check, solver_checks

POSE_AGREEMENT_Z = 3.0  # two poses (one pair): |m_b − m_d| / σ above this fails (mass)
POSE_AGREEMENT_COG_Z = 3.5  # two poses: the same per centre-of-mass component (three comparisons)
# more poses: ``pose_agreement_limits`` (Šidák over the pairs, the same family-wise rate as one pair)
MAX_CONDITION = 1e6
MIN_MASS_Z = 10.0  # mass / σ_mass below this: no payload worth the name (or none mounted)
MAX_MASS_KG = 50.0  # beyond any arm this agent is meant for: a unit or gain mistake
MIN_SWEEP_SAMPLES = 50  # constant-speed samples per sweep used
MAX_RESIDUAL_TO_NOISE = 4.0  # residual RMS / sensor noise of a (sweep, joint) group
GAIN_CONSISTENCY_TOL = 0.05  # |measured / modelled torque − 1| per joint, plus 4 σ of that ratio
GAIN_CHECK_MIN_SNR = 20.0  # only joints whose modelled torque peaks at this many noise σ


def _two_sided_rate(z: float) -> float:
    """P(|Z| > z) for Z ~ N(0, 1)."""
    return math.erfc(z / math.sqrt(2.0))


def pose_agreement_limits(n_pairs: int) -> tuple[float, float]:
    """(mass limit, centre-of-mass limit per axis) in σ for a procedure whose poses make ``n_pairs`` pairs.

    One pair (two poses): ``POSE_AGREEMENT_Z`` and ``POSE_AGREEMENT_COG_Z``. More pairs: Šidák, each test's
    two-sided rate α₁ of the one-pair limit becomes 1 − (1 − α₁)^(1/n_pairs), so that the family-wise
    false-refusal rate of all pairs stays that of one pair (``pose_agreement_family_rate``).
    """
    n = max(int(n_pairs), 1)
    if n == 1:
        return POSE_AGREEMENT_Z, POSE_AGREEMENT_COG_Z

    def limit(z1: float) -> float:
        alpha = -math.expm1(math.log1p(-_two_sided_rate(z1)) / n)
        return NormalDist().inv_cdf(1.0 - alpha / 2.0)

    return limit(POSE_AGREEMENT_Z), limit(POSE_AGREEMENT_COG_Z)


def pose_agreement_family_rate(n_pairs: int) -> float:
    """The false-refusal rate of the whole pose-agreement check at ``pose_agreement_limits(n_pairs)`` when every
    z is N(0, 1): at most 1 − Π(1 − α) over its 4·n_pairs tests (Šidák's inequality: equality for independent
    z's, less for correlated ones)."""
    n = max(int(n_pairs), 1)
    zm, zc = pose_agreement_limits(n)
    return 1.0 - ((1.0 - _two_sided_rate(zm)) * (1.0 - _two_sided_rate(zc)) ** 3) ** n


def noise_estimate(y: np.ndarray) -> float:
    """Sensor noise σ of a smooth signal sampled densely: std of second differences / √6."""
    y = np.asarray(y, float)
    if len(y) < 5:
        return float("nan")
    return float(np.std(np.diff(y, 2)) / math.sqrt(6.0))


def _output_jacobian(theta: np.ndarray) -> np.ndarray:
    """∂[m, cx, cy, cz]/∂θ at θ = [m, m·c] (4×4)."""
    J = np.zeros((4, 4))
    J[0, 0] = 1.0
    m = theta[0]
    J[1:, 0] = -theta[1:] / m ** 2
    J[1:, 1:] = np.eye(3) / m
    return J


def _pose_fit(res: wls.FitResult, groups: list[wls.Group], rows: np.ndarray, dY: list[np.ndarray],
              eps: dict[int, np.ndarray], gain_rel_std: np.ndarray | None,
              absorbed: Callable[[np.ndarray], list[np.ndarray] | None] | None = None) -> dict[str, Any]:
    """One pose's own fit ``res`` of ``groups``: θ, its noise covariance, its first-order response to the errors.

    ``G`` (4 × joints): ∂θ/∂ε_j of a relative gain error of joint j (``wls.gain_covariance``);
    ``S`` (K × 4): ∂θ/∂p_k of DH length k, less what the calibration's gain fit absorbed
    (``general.kinematic_sensitivities``); ``rows`` selects this pose's rows of the stacked groups. ``absorbed``:
    the calibration's stored response on this pose's rows for θ (``general.length_absorption``), in place of ``eps``.
    """
    theta, w, inv = res.theta, res.weights, res.normal_inverse
    Y = np.vstack([g.Y for g in groups])
    pred = Y @ theta
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    out = {"res": res, "theta": theta, "cov": res.cov, "G": None, "S": None}
    if gain_rel_std is not None:
        G = np.zeros((len(theta), len(gain_rel_std)))
        for j in range(len(gain_rel_std)):
            r = joint_of_row == j
            if r.any():
                G[:, j] = inv @ (Y[r].T @ (w[r] * pred[r]))
        out["G"] = G
    if dY:
        S = []
        extra = None if absorbed is None else absorbed(theta)
        for k, d in enumerate(dY):
            v = d[rows] @ theta + (0.0 if extra is None else extra[k])
            for j, e in eps.items():
                v[joint_of_row == j] -= e[k] * pred[joint_of_row == j]
            S.append(inv @ (Y.T @ (w * v)))
        out["S"] = np.array(S)
    return out


def evaluate(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: Estimate, *,
             gain_rel_std: Iterable[float] | None = None, length_std_m: float | None = None,
             gain_reference: tuple[Iterable[float], Iterable[int]] | None = None,
             others: Sequence[Estimate] = (), systematics: Any = None,
             model: FittedModel | None = None) -> dict[str, Any]:
    """Every check on one identification; ``passed`` is True only if all passed (see the module docstring).

    ``others``: the other solvers' estimates on the same data; the primary must agree with each
    that reports an uncertainty (``solver_checks``).

    ``gain_rel_std``, ``length_std_m`` and ``gain_reference``: the uncertainty terms the primary
    estimate was solved with (``general.solve``); the pose-agreement check propagates the same
    terms through both per-pose fits. Without them it compares on the sensor noise alone.
    ``systematics`` (``evaluation.systematics.Systematics``): the real arm's terms the estimate
    carries; each pose's own response to them enters the pose comparison.
    ``model``: the analysis' fitted model of ``deltas`` with ``gain_rel_std`` (made here if None): its
    combined and per-pose fits are the ones checked.
    """
    q: dict[str, Any] = {"passed": True, "reasons": []}
    checks: list[dict[str, Any]] = []
    if model is None:
        model = general.fit_model(deltas, kin, gain_rel_std)
    sweeps, groups = list(model.sweeps), list(model.groups)
    gain_std = None if gain_rel_std is None else np.asarray(list(gain_rel_std), float)
    length_std = float(length_std_m) if length_std_m and length_std_m > 0 else 0.0

    # --- pose agreement -------------------------------------------------------------------
    per_pose: dict[str, dict[str, Any]] = {}
    fits: dict[str, dict[str, Any]] = {}
    poses = sorted({d.key.pose for d in sweeps})
    pose_of = {d.key.name: d.key.pose for d in sweeps}
    dY: list[np.ndarray] = []
    eps: dict[int, np.ndarray] = {}
    absorb: Callable[[np.ndarray, str], list[np.ndarray] | None] | None = None  # the calibration's own response
    if length_std > 0 and len(poses) >= 2 and groups:
        dY = general.model_length_derivatives(model)
        if length_response.of_reference(gain_reference) is not None:
            absorb = lambda theta, pose: general.length_absorption(  # noqa: E731
                [d for d in sweeps if d.key.pose == pose], kin, model.groups_of(pose), theta, [], gain_reference)
        elif gain_reference is not None:
            eps = general.absorbed_length_error(sweeps, groups, dY, gain_reference)
    row_pose = np.repeat([pose_of[g.sweep] for g in groups], [len(g.y) for g in groups])
    for pose in poses:
        try:
            f = _pose_fit(model.fit(pose), model.groups_of(pose), row_pose == pose, dY, eps, gain_std,
                          None if absorb is None else (lambda theta, p=pose: absorb(theta, p)))
            theta = f["theta"] = f["theta"] - (0.0 if systematics is None else systematics.shift(pose))  # Term.shift
            if not theta[0] > 0:
                raise DataError(f"mass {theta[0]:.4f} kg is not positive")
            J = _output_jacobian(theta)
            cov = f["cov"]  # noise only; the systematic terms below
            if f["G"] is not None:
                cov = cov + f["G"] @ np.diag(gain_std ** 2) @ f["G"].T
            if f["S"] is not None:
                cov = cov + length_std ** 2 * f["S"].T @ f["S"]
            if systematics is not None:
                f["A"], f["A_var"] = systematics.sensitivities(pose)
                cov = cov + (f["A"] * f["A_var"]) @ f["A"].T
            var = np.diag(J @ cov @ J.T)
        except (DataError, np.linalg.LinAlgError) as exc:
            q["reasons"].append(f"pose {pose} alone: not solvable ({exc})")
            continue
        fits[pose] = dict(f, J=J)
        per_pose[pose] = {"mass_kg": float(theta[0]), "mass_std_kg": float(np.sqrt(max(var[0], 0.0))),
                          "cog_mm": [1000 * float(v) for v in theta[1:] / theta[0]],
                          "cog_std_mm": [1000 * float(np.sqrt(max(v, 0.0))) for v in var[1:]],
                          "condition_number": f["res"].condition_number}
    q["per_pose"] = per_pose
    q["pose_agreement_sigma"] = ("noise of each pose's own fit (independent)"
                                 + (" + drive-gain uncertainty" if gain_std is not None else "")
                                 + (f" + DH-length uncertainty {1000 * length_std:.3g} mm" if length_std > 0 else "")
                                 + (f" + {systematics.describe()}" if systematics is not None and systematics.terms
                                    else "")
                                 + ("; the common terms propagated through both poses' fits, only their "
                                    "difference counted" if gain_std is not None or length_std > 0
                                    or systematics is not None else ""))
    hint = ("" if gain_std is not None else "; with uncalibrated drive gains their error is not in σ: "
            "run `payload-agent calibrate`")
    names = sorted(per_pose)
    n_pairs = len(names) * (len(names) - 1) // 2
    z_mass, z_cog = pose_agreement_limits(n_pairs)
    q["pose_agreement_limits"] = {"pairs": n_pairs, "mass_z": z_mass, "cog_z": z_cog,
                                  "family_false_refusal_rate": pose_agreement_family_rate(n_pairs)}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ea, eb = per_pose[a], per_pose[b]
            std_diff = _difference_std(fits[a], fits[b], gain_std, length_std)
            sigma = float(std_diff[0])
            diff = ea["mass_kg"] - eb["mass_kg"]
            z = diff / sigma if sigma > 0 else (0.0 if diff == 0 else math.inf)
            checks.append(_check(f"mass pose {a} vs pose {b}", abs(z), z_mass, abs(z) <= z_mass,
                                 f"mass from pose {a} ({ea['mass_kg']:.4f} kg) and from pose {b} ({eb['mass_kg']:.4f} kg) "
                                 f"differ by {abs(z):.1f} σ (limit {z_mass:.2f} σ): friction not cancelled, "
                                 f"or the tool moved between poses?{hint}",
                                 difference_kg=diff, sigma_kg=sigma, z=z, limit_z=z_mass))
            for k, axis in enumerate("xyz"):
                s = 1000 * float(std_diff[k + 1])
                dc = ea["cog_mm"][k] - eb["cog_mm"][k]
                zc = dc / s if s > 0 else (0.0 if dc == 0 else math.inf)
                checks.append(_check(f"cog {axis} pose {a} vs pose {b}", abs(zc), z_cog, abs(zc) <= z_cog,
                                     f"centre of mass {axis} from pose {a} ({ea['cog_mm'][k]:.2f} mm) and from pose {b} "
                                     f"({eb['cog_mm'][k]:.2f} mm) differ by {abs(zc):.1f} σ "
                                     f"(limit {z_cog:.2f} σ){hint}",
                                     difference_mm=dc, sigma_mm=s, z=zc, limit_z=z_cog))
    if len(per_pose) < 2:
        q["reasons"].append("fewer than two poses solvable on their own: no pose-agreement check")

    # --- the combined general fit: conditioning, mass, residuals, gains -------------------
    try:
        res = model.fit(ALL)
    except DataError as exc:
        q["reasons"].append(f"general fit impossible: {exc}")
        res = None
    if res is not None:
        theta, cov = res.theta, res.cov
        cond = res.condition_number
        checks.append(_check("condition number", cond, MAX_CONDITION, cond <= MAX_CONDITION,
                             f"ill-conditioned fit (condition number {cond:.3g} > {MAX_CONDITION:g}): "
                             "the sweeps do not observe every parameter; use a procedure with two tool orientations"))
        m, sm = float(theta[0]), float(np.sqrt(max(cov[0, 0], 0.0)))
        zm = m / sm if sm > 0 else math.inf
        checks.append(_check("mass significance", zm, MIN_MASS_Z, zm >= MIN_MASS_Z,
                             f"identified mass {m:.4f} ± {sm:.4f} kg is only {zm:.1f} σ above zero "
                             f"(at least {MIN_MASS_Z:g} σ needed): is the tool mounted for the loaded run "
                             "and removed for the empty one?", mass_kg=m, mass_std_kg=sm))
        checks.append(_check("mass upper bound", m, MAX_MASS_KG, m <= MAX_MASS_KG,
                             f"identified mass {m:.2f} kg exceeds {MAX_MASS_KG:g} kg: check effort.unit and "
                             "effort.gains_nm_per_unit"))
        worst = None
        for g in groups:
            r = g.y - g.Y @ theta
            noise = noise_estimate(g.y)
            ratio = float(np.sqrt(np.mean(r ** 2)) / noise) if noise > 0 else math.inf
            if worst is None or ratio > worst[0]:
                worst = (ratio, g.label, float(np.sqrt(np.mean(r ** 2))), noise)
        if worst is not None:
            ratio, label, rms, noise = worst
            checks.append(_check("residual / noise (worst sweep and joint)", ratio, MAX_RESIDUAL_TO_NOISE,
                                 ratio <= MAX_RESIDUAL_TO_NOISE,
                                 f"{label}: residual RMS {rms:.3f} N·m is {ratio:.1f} × the sensor noise "
                                 f"({noise:.3f} N·m; limit {MAX_RESIDUAL_TO_NOISE:g} ×): the model does not fit "
                                 "this joint (wrong drive gain, kinematics, or a collision/disturbance?)",
                                 where=label, residual_rms_nm=rms, noise_nm=noise))
        checks.extend(_gain_checks(groups, theta))

    # --- a tool cable or hose on the wrist ---------------------------------------------------
    cable = cable_check.check(deltas, kin, gain_rel_std=gain_std, model=model)
    checks.append(cable)

    # --- samples --------------------------------------------------------------------------
    if sweeps:
        fewest = min(sweeps, key=lambda d: len(d.q))
        n = len(fewest.q)
        checks.append(_check("samples per sweep (fewest)", n, MIN_SWEEP_SAMPLES, n >= MIN_SWEEP_SAMPLES,
                             f"{fewest.key.name}: only {n} constant-speed samples (at least {MIN_SWEEP_SAMPLES}): "
                             "lower procedure.speed_percent or widen the sweep range", where=fewest.key.name))

    checks.extend(solver_checks(primary, others, hint, min_mass_z=MIN_MASS_Z, max_mass_kg=MAX_MASS_KG))
    for c in checks:
        if not c["passed"] and c.get("reason"):
            q["reasons"].append(c["reason"])
    q["checks"] = checks
    q["primary"] = {"solver": primary.solver, "condition_number": primary.condition_number,
                    "mass_std_kg": primary.mass_std_kg,
                    "cog_std_mm": None if primary.cog_std_m is None else [1000 * v for v in primary.cog_std_m],
                    "max_residual_rms_nm": max(primary.residual_rms_nm.values(), default=None)}
    q["passed"] = all(c["passed"] for c in checks) and len(per_pose) >= 2 and res is not None
    return q


def _difference_std(fa: dict[str, Any], fb: dict[str, Any], gain_std: np.ndarray | None,
                    length_std: float) -> np.ndarray:
    """Standard deviation of o_a − o_b, o = [m, cx, cy, cz] of two poses' own fits.

    Systematic terms (``A``: ∂θ/∂p of each pose's fit, ``A_var``: σ_p² signed, the same parameters in
    both) are differenced like the gains.

    Noise: independent (different sweeps), J_a·Σ_a·J_aᵀ + J_b·Σ_b·J_bᵀ. Drive gains and DH lengths:
    the same errors act on both fits, so their first-order effects are differenced before squaring,
    D·diag(σ²)·Dᵀ with D = J_a·G_a − J_b·G_b (gains) and J_a·S_aᵀ − J_b·S_bᵀ (lengths).
    """
    Ja, Jb = fa["J"], fb["J"]
    cov = Ja @ fa["cov"] @ Ja.T + Jb @ fb["cov"] @ Jb.T
    if gain_std is not None and fa["G"] is not None and fb["G"] is not None:
        D = Ja @ fa["G"] - Jb @ fb["G"]
        cov = cov + D @ np.diag(gain_std ** 2) @ D.T
    if length_std > 0 and fa["S"] is not None and fb["S"] is not None:
        D = Ja @ fa["S"].T - Jb @ fb["S"].T
        cov = cov + length_std ** 2 * D @ D.T
    if fa.get("A") is not None and fb.get("A") is not None:  # systematic terms: the same parameters in both
        D = Ja @ fa["A"] - Jb @ fb["A"]
        cov = cov + (D * fa["A_var"]) @ D.T
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def _gain_checks(groups: Iterable[wls.Group], theta: np.ndarray) -> list[dict[str, Any]]:
    """Per joint: measured / modelled torque ratio k (LS over all its rows) must be 1 within tolerance."""
    by_joint: dict[int, list[wls.Group]] = {}
    for g in groups:
        by_joint.setdefault(g.joint, []).append(g)
    out = []
    for j, gs in sorted(by_joint.items()):
        pred = np.concatenate([g.Y @ theta for g in gs])
        meas = np.concatenate([g.y for g in gs])
        noise = float(np.median([noise_estimate(g.y) for g in gs]))
        if not np.max(np.abs(pred)) >= GAIN_CHECK_MIN_SNR * noise or not pred @ pred > 0:
            continue
        k = float(pred @ meas / (pred @ pred))
        r = meas - k * pred
        tau = max(wls.autocorrelation_time(g.y - g.Y @ theta)[0] for g in gs)
        sk = float(np.sqrt(np.mean(r ** 2) * tau / (pred @ pred)))
        limit = GAIN_CONSISTENCY_TOL + 4.0 * sk
        out.append(_check(f"drive gain consistency joint {j + 1}", abs(k - 1.0), limit, abs(k - 1.0) <= limit,
                          f"joint {j + 1} measures {k:.3f} × the torque the other joints imply (limit ±{limit:.3f}): "
                          f"its drive gain (effort.gains_nm_per_unit[{j}]) is off; run `payload-agent calibrate` "
                          "with a known reference payload", ratio=k, ratio_std=sk))
    return out


def require_passed(result: RunResult | dict[str, Any]) -> None:
    """Raise QualityGateError listing every failed check (with its numbers) unless all passed."""
    quality = result.quality if isinstance(result, RunResult) else result.get("quality", {})
    if not quality:
        raise QualityGateError("no quality checks were recorded for this result; re-run `payload-agent solve` on it")
    if quality.get("passed"):
        return
    failed = [c for c in quality.get("checks", []) if not c.get("passed")]
    lines = []
    for c in failed:
        line = f"{c['check']}: {c.get('value', float('nan')):.4g} (limit {c.get('limit', float('nan')):.4g})"
        if c.get("reason"):
            line += f" — {c['reason']}"
        lines.append(line)
    listed = {c.get("reason") for c in failed}
    lines += [r for r in quality.get("reasons", []) if r not in listed]
    raise QualityGateError("quality gate failed; nothing is written to the robot:\n  - " + "\n  - ".join(lines))
