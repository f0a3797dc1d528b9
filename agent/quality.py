"""Quality gates: redundant checks on an identification, and their enforcement.

``evaluate`` computes every check on the baseline-subtracted sweeps (whatever the primary
solver, the checks use the general weighted fit, which has residuals and a covariance);
``require_passed`` raises QualityGateError listing every failed check with its numbers.
The runner calls it before anything is written to a controller and for the exit code.

Each check is ``{"check": name, "value": v, "limit": l, "passed": bool, ...}``. Limits are
set so that simulated runs with realistic noise, friction drift and ±3 % gain errors pass,
while a grossly wrong drive gain (≥ 10 % on one joint), a missing tool, or disagreeing
poses fail:

- pose agreement: poses b and d each determine mass and all three centre-of-mass components
  on their own (joints 2–3 see the lever along the arm, the wrist joints the rest); the two
  independent estimates must agree within their combined uncertainty;
- conditioning of the combined fit;
- mass positive, clearly above its own uncertainty (a tool is mounted) and below a sane bound;
- enough constant-speed samples in every sweep;
- residual RMS of every (sweep, joint) no more than a few times the sensor noise, estimated
  from the same data (second differences), so nothing is assumed about the robot;
- drive-gain consistency: with θ fitted on all joints, each well-loaded joint's measured
  torque must match the model to within a few per cent (a larger mismatch is a wrong drive
  gain, which no other check sees because it scales both poses alike).
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

from payload_agent.delta import DeltaSweep
from payload_agent.errors import DataError, QualityGateError
from payload_agent.kinematics import Kinematics
from payload_agent.planner import SweepKey
from payload_agent.results import Estimate, RunResult
from payload_agent.solvers import general

POSE_AGREEMENT_Z = 3.0  # |m_b − m_d| / σ above this fails (mass)
POSE_AGREEMENT_COG_Z = 3.5  # the same per centre-of-mass component (three comparisons)
MAX_CONDITION = 1e6
MIN_MASS_Z = 10.0  # mass / σ_mass below this: no payload worth the name (or none mounted)
MAX_MASS_KG = 50.0  # beyond any arm this agent is meant for: a unit or gain mistake
MIN_SWEEP_SAMPLES = 50  # constant-speed samples per sweep used
MAX_RESIDUAL_TO_NOISE = 4.0  # residual RMS / sensor noise of a (sweep, joint) group
GAIN_CONSISTENCY_TOL = 0.05  # |measured / modelled torque − 1| per joint, plus 4 σ of that ratio
GAIN_CHECK_MIN_SNR = 20.0  # only joints whose modelled torque peaks at this many noise σ


def noise_estimate(y: np.ndarray) -> float:
    """Sensor noise σ of a smooth signal sampled densely: std of second differences / √6."""
    y = np.asarray(y, float)
    if len(y) < 5:
        return float("nan")
    return float(np.std(np.diff(y, 2)) / math.sqrt(6.0))


def _check(name: str, value: float, limit: float, passed: bool, reason: str | None, **extra: Any) -> dict[str, Any]:
    c = {"check": name, "value": float(value), "limit": float(limit), "passed": bool(passed), **extra}
    if not passed and reason:
        c["reason"] = reason
    return c


def evaluate(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: Estimate) -> dict[str, Any]:
    """Every check on one identification; ``passed`` is True only if all passed (see the module docstring)."""
    q: dict[str, Any] = {"passed": True, "reasons": []}
    checks: list[dict[str, Any]] = []
    sweeps = general.select_sweeps(deltas)
    groups = general.build_groups(sweeps, kin)

    # --- pose agreement -------------------------------------------------------------------
    per_pose: dict[str, dict[str, Any]] = {}
    poses = sorted({d.key.pose for d in sweeps})
    pose_of = {d.key.name: d.key.pose for d in sweeps}
    for pose in poses:
        try:
            res = general.fit([g for g in groups if pose_of[g.sweep] == pose])
            theta, cov = res["theta"], res["cov"]
            if not theta[0] > 0:
                raise DataError(f"mass {theta[0]:.4f} kg is not positive")
            c, cov_c = general.cog_with_covariance(theta, cov)
        except (DataError, np.linalg.LinAlgError) as exc:
            q["reasons"].append(f"pose {pose} alone: not solvable ({exc})")
            continue
        per_pose[pose] = {"mass_kg": float(theta[0]), "mass_std_kg": float(np.sqrt(cov[0, 0])),
                          "cog_mm": [1000 * float(v) for v in c],
                          "cog_std_mm": [1000 * float(np.sqrt(max(v, 0.0))) for v in np.diag(cov_c)],
                          "condition_number": res["cond"]}
    q["per_pose"] = per_pose
    names = sorted(per_pose)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ea, eb = per_pose[a], per_pose[b]
            sigma = math.hypot(ea["mass_std_kg"], eb["mass_std_kg"])
            diff = ea["mass_kg"] - eb["mass_kg"]
            z = diff / sigma if sigma > 0 else (0.0 if diff == 0 else math.inf)
            checks.append(_check(f"mass pose {a} vs pose {b}", abs(z), POSE_AGREEMENT_Z, abs(z) <= POSE_AGREEMENT_Z,
                                 f"mass from pose {a} ({ea['mass_kg']:.4f} kg) and from pose {b} ({eb['mass_kg']:.4f} kg) "
                                 f"differ by {abs(z):.1f} σ (limit {POSE_AGREEMENT_Z:g} σ): friction not cancelled, "
                                 "or the tool moved between poses?",
                                 difference_kg=diff, sigma_kg=sigma, z=z, limit_z=POSE_AGREEMENT_Z))
            for k, axis in enumerate("xyz"):
                s = math.hypot(ea["cog_std_mm"][k], eb["cog_std_mm"][k])
                dc = ea["cog_mm"][k] - eb["cog_mm"][k]
                zc = dc / s if s > 0 else (0.0 if dc == 0 else math.inf)
                checks.append(_check(f"cog {axis} pose {a} vs pose {b}", abs(zc), POSE_AGREEMENT_COG_Z,
                                     abs(zc) <= POSE_AGREEMENT_COG_Z,
                                     f"centre of mass {axis} from pose {a} ({ea['cog_mm'][k]:.2f} mm) and from pose {b} "
                                     f"({eb['cog_mm'][k]:.2f} mm) differ by {abs(zc):.1f} σ "
                                     f"(limit {POSE_AGREEMENT_COG_Z:g} σ)",
                                     difference_mm=dc, sigma_mm=s, z=zc, limit_z=POSE_AGREEMENT_COG_Z))
    if len(per_pose) < 2:
        q["reasons"].append("fewer than two poses solvable on their own: no pose-agreement check")

    # --- the combined general fit: conditioning, mass, residuals, gains -------------------
    try:
        res = general.fit(groups)
    except DataError as exc:
        q["reasons"].append(f"general fit impossible: {exc}")
        res = None
    if res is not None:
        theta, cov = res["theta"], res["cov"]
        checks.append(_check("condition number", res["cond"], MAX_CONDITION, res["cond"] <= MAX_CONDITION,
                             f"ill-conditioned fit (condition number {res['cond']:.3g} > {MAX_CONDITION:g}): "
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

    # --- samples --------------------------------------------------------------------------
    if sweeps:
        fewest = min(sweeps, key=lambda d: len(d.q))
        n = len(fewest.q)
        checks.append(_check("samples per sweep (fewest)", n, MIN_SWEEP_SAMPLES, n >= MIN_SWEEP_SAMPLES,
                             f"{fewest.key.name}: only {n} constant-speed samples (at least {MIN_SWEEP_SAMPLES}): "
                             "lower procedure.speed_percent or widen the sweep range", where=fewest.key.name))

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


def _gain_checks(groups: Iterable[general.Group], theta: np.ndarray) -> list[dict[str, Any]]:
    """Per joint: measured / modelled torque ratio k (LS over all its rows) must be 1 within tolerance."""
    by_joint: dict[int, list[general.Group]] = {}
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
        tau = max(general.autocorrelation_time(g.y - g.Y @ theta)[0] for g in gs)
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
