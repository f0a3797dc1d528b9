"""The general solver: weighted least squares on Δτ = Y(q, q̇)·θ over every loaded joint and sweep.

θ = [m, m·cx, m·cy, m·cz] (c in the flange frame, SI). Rows come from every joint whose
regressor rows are not all zero (joint 1 has a vertical axis and never carries the
payload's weight) and from every constant-speed sample of every sweep. Where a
bidirectional sweep was combined (direction "both", see ``payload_agent.analysis.combine``) the
combined sweep replaces its "up" and "down" halves.

Model: the static gravity regressor (``Kinematics.payload_regressor``) plus the centripetal
force the arm must exert to carry the payload round the moving joint's axis at the
sweep's constant speed ω. That term is even in ω, so combining the two directions does
not remove it; at 20 % of the EC66's maximum speed it biases the centre of mass by about
1 mm if left out. Only its part linear in θ is kept (the rest, ∝ m·|c|²·ω², is a
rotational-inertia effect below 0.05 N·m at these speeds).

Weights: one unweighted fit, then the residual variance σ²(sweep, joint) of each group,
then the fit again with weights 1/σ². Covariance: the samples of one sweep are not
independent (interpolation onto the combined grid, friction ripple, unmodelled slow
effects), so the textbook s²·(YᵀWY)⁻¹ is too optimistic. The covariance is a sandwich
A⁻¹·B·A⁻¹ with A = YᵀWY and B the long-run variance of the weighted scores, estimated
sweep by sweep with a Bartlett (Newey–West) kernel whose bandwidth follows the residuals'
own autocorrelation length; it never goes below the independent-noise covariance. An
optional relative drive-gain uncertainty per joint (from ``payload-agent calibrate``) is
propagated on top, and so is an optional standard uncertainty of the DH lengths
(``robot.kinematics.length_uncertainty_mm``): the regressor is built from the nominal
lengths, the arm's torques follow its true ones, and that systematic error does not
average out however many samples are taken (``kinematic_covariance``: first-order
sensitivity of θ̂ to every non-zero a_i and d_i, which is exact for Y since positions are
linear in the lengths; with a gain calibration, the part of the error its fit absorbed is
taken out).

The centre of mass c = (m·c)/m gets its covariance from the delta method.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import SweepKey
from payload_agent.solvers.results import Estimate

NAME = "general"
GRAVITY_JOINTS = (1, 2, 3, 4, 5)  # 0-based: joints 2..6
ZERO_ROW_TOL = 1e-9  # N·m per unit θ: a joint whose rows are all below this carries no payload torque
SIGMA_FLOOR_NM = 1e-9  # noise-free data: keep the weights finite
HAC_WINDOW_C = 5.0  # Sokal's automatic window: smallest lag M with M >= C·τ_int
HAC_MAX_FRACTION = 0.25  # bandwidth at most this fraction of a sweep's samples


@dataclass
class Group:
    """The rows of one (sweep, joint) pair."""

    label: str
    sweep: str
    Y: np.ndarray  # (n, 4)
    y: np.ndarray  # (n,)
    joint: int = -1  # 0-based joint of these rows (-1: unknown)


def select_sweeps(deltas: dict[SweepKey, DeltaSweep], *, poses: Iterable[str] | None = None,
                  use_combined: bool = True) -> list[DeltaSweep]:
    """Combined sweeps where available, else every plain sweep; optionally only some poses."""
    wanted = None if poses is None else set(poses)
    chosen = [d for k, d in deltas.items() if wanted is None or k.pose in wanted]
    if use_combined:
        both = {(d.key.pose, d.key.joint, d.key.speed_percent) for d in chosen if d.key.direction == "both"}
        chosen = [d for d in chosen
                  if d.key.direction == "both" or (d.key.pose, d.key.joint, d.key.speed_percent) not in both]
    else:
        chosen = [d for d in chosen if d.key.direction != "both"]
    return sorted(chosen, key=lambda d: (d.key.pose, d.key.joint, d.key.direction, d.key.speed_percent))


def centripetal_regressor(kin: Kinematics, q: np.ndarray, joints: Iterable[int], moving: int,
                          speed_rad_s: float) -> np.ndarray:
    """Rows added to Y(q) by carrying the payload round joint ``moving`` at constant speed ω.

    The payload's centre of mass x = p + R·c moves on a circle about the moving joint's axis
    (z_k through o_k) with acceleration ẍ = ω²·(z_k z_kᵀ − I)(x − o_k); the arm supplies the
    force m·ẍ, which loads joint j with z_j·((x − o_j) × m·ẍ). Expanded, this is linear in θ
    except for a term in m·c·cᵀ (a rotational-inertia effect, left out). Same sign convention
    as ``Kinematics.payload_regressor`` (support force m·g·ẑ).
    """
    joints = tuple(joints)
    w2 = float(speed_rad_s) ** 2
    if w2 == 0.0:
        return np.zeros((len(joints), 4))
    pose = kin.pose(q)
    p, R = pose.flange[:3, 3], pose.flange[:3, :3]
    zk, ok = pose.axis(moving), pose.origin(moving)
    A = np.outer(zk, zk) - np.eye(3)
    f_m = A @ (p - ok)  # centripetal acceleration of the flange origin per ω²
    rows = []
    for j in joints:
        z, a = pose.axis(j), p - pose.origin(j)
        rows.append(w2 * np.concatenate(([z @ np.cross(a, f_m)], R.T @ (A @ np.cross(z, a) + np.cross(f_m, z)))))
    return np.array(rows)


def regressor(kin: Kinematics, q: np.ndarray, joints: Iterable[int], moving: int | None = None,
              speed_rad_s: float = 0.0) -> np.ndarray:
    """Δτ_joints = regressor · θ at angles q, with joint ``moving`` turning at ``speed_rad_s`` (static: 0)."""
    joints = tuple(joints)
    Y = kin.payload_regressor(q, joints)
    if moving is not None and speed_rad_s:
        Y = Y + centripetal_regressor(kin, q, joints, moving, speed_rad_s)
    return Y


def build_groups(sweeps: list[DeltaSweep], kin: Kinematics,
                 joints: Iterable[int] = GRAVITY_JOINTS) -> list[Group]:
    joints = tuple(joints)
    groups = []
    # vectorised: the payload's Newton–Euler regressor at constant speed of the moving joint,
    # first four columns, is exactly regressor() (gravity + centripetal), ~500x faster per sweep
    from payload_agent.solvers.dynamic import payload_regressor

    for d in sweeps:
        qd = np.zeros_like(d.q)
        qd[:, d.moving] = d.speed_rad_s
        Y = payload_regressor(kin, d.q, qd, np.zeros_like(d.q))[:, list(joints), :4]  # (n, len(joints), 4)
        for c, j in enumerate(joints):
            Yj = Y[:, c, :]
            if np.max(np.abs(Yj)) < ZERO_ROW_TOL:
                continue
            groups.append(Group(f"{d.key.name}/j{j + 1}", d.key.name, Yj, np.asarray(d.dtau[:, j], float), j))
    return groups


def autocorrelation_time(x: np.ndarray, *, c: float = HAC_WINDOW_C, max_lag: int | None = None) -> tuple[float, int]:
    """Integrated autocorrelation time τ = 1 + 2·Σρ_k of a series, and the window M it used.

    Sokal's automatic window: the smallest M with M >= c·τ(M). τ ≈ 1 for independent
    samples; a series whose samples come in correlated runs of length L has τ ≈ L, i.e. it
    carries as much information as n/τ independent samples.
    """
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    max_lag = n // 2 if max_lag is None else min(max_lag, n - 1)
    var = float(x @ x)
    if n < 3 or var <= 0.0 or max_lag < 1:
        return 1.0, 0
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[: max_lag + 1] / var
    tau = 1.0
    for m in range(1, max_lag + 1):
        tau += 2.0 * acf[m]
        if m >= c * tau:
            return max(tau, 1.0), m
    return max(tau, 1.0), max_lag


def _long_run_scores(U: np.ndarray, bandwidth: int) -> np.ndarray:
    """Σ_l k(l)·Σ_i u_i u_{i+l}ᵀ (both signs of l) with the Bartlett kernel k(l) = 1 − |l|/(L+1)."""
    B = U.T @ U
    for lag in range(1, bandwidth + 1):
        G = U[lag:].T @ U[:-lag]
        B += (1.0 - lag / (bandwidth + 1.0)) * (G + G.T)
    return B


def _wls(Y: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted LS via a column-scaled QR-free lstsq; returns θ and (YᵀWY)⁻¹."""
    sw = np.sqrt(w)
    A = Y * sw[:, None]
    b = y * sw
    scale = np.sqrt(np.sum(A ** 2, axis=0))
    scale[scale == 0] = 1.0
    As = A / scale
    theta_s, *_ = np.linalg.lstsq(As, b, rcond=None)
    theta = theta_s / scale
    normal_s = As.T @ As
    inv = np.linalg.pinv(normal_s) / np.outer(scale, scale)
    return theta, inv


def fit(groups: list[Group], gain_rel_std: Iterable[float] | None = None) -> dict:
    """Two-pass weighted fit. Returns θ, its covariance, per-group σ and residual RMS, condition number.

    ``cov`` is the autocorrelation-robust covariance (see the module docstring), ``cov_iid`` the
    textbook one for independent noise, ``inflation`` the largest ratio of their diagonals and
    ``tau`` each sweep's autocorrelation time, ``w`` the row weights and ``inv`` (YᵀWY)⁻¹ (for
    ``kinematic_covariance``). ``gain_rel_std`` (per joint, 0-based, relative):
    the standard uncertainty of each drive gain, added to ``cov`` through ∂θ/∂gain.
    """
    if not groups:
        raise DataError("general: no sweep carries any payload torque (no usable joint rows)")
    Y = np.vstack([g.Y for g in groups])
    y = np.concatenate([g.y for g in groups])
    n, p = Y.shape
    if n <= p:
        raise DataError(f"general: only {n} samples for {p} unknowns")
    idx = np.repeat(np.arange(len(groups)), [len(g.y) for g in groups])

    theta0, _ = _wls(Y, y, np.ones(n))
    r0 = y - Y @ theta0
    dof_factor = n / (n - p)
    sigma = np.array([np.sqrt(np.mean(r0[idx == i] ** 2) * dof_factor) for i in range(len(groups))])
    sigma = np.maximum(sigma, SIGMA_FLOOR_NM)
    w = 1.0 / sigma[idx] ** 2

    theta, inv = _wls(Y, y, w)
    r = y - Y @ theta
    s2 = float(r @ (w * r) / (n - p))
    cov_iid = s2 * inv

    # sandwich: long-run variance of the weighted scores, sweep by sweep (the joints of one
    # sample share its instant, so their scores are summed before the lags are taken)
    B = np.zeros((p, p))
    tau: dict[str, float] = {}
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    for sweep in dict.fromkeys(g.sweep for g in groups):
        members = [i for i, g in enumerate(groups) if g.sweep == sweep]
        U = sum(groups[i].Y * (w[starts[i]:starts[i + 1]] * r[starts[i]:starts[i + 1]])[:, None] for i in members)
        z = sum(r[starts[i]:starts[i + 1]] / sigma[i] for i in members)  # normalised residual per instant
        m = len(z)
        t, lag = autocorrelation_time(z, max_lag=max(1, int(HAC_MAX_FRACTION * m)))
        tau[sweep] = t
        B += _long_run_scores(U, lag) * dof_factor
    cov = inv @ B @ inv
    # never below the independent-noise covariance (the kernel estimate is itself noisy)
    ratio = np.sqrt(np.maximum(np.diag(cov), 0.0) / np.maximum(np.diag(cov_iid), 1e-300))
    if np.any(ratio < 1.0):
        f = np.sqrt(np.maximum(1.0 / ratio, 1.0))
        cov = cov * np.outer(f, f)
    if gain_rel_std is not None:
        cov = cov + gain_covariance(groups, Y, w, inv, theta, gain_rel_std)

    normal = (Y * w[:, None]).T @ Y
    d = 1.0 / np.sqrt(np.diag(normal))
    cond = float(np.linalg.cond(normal * np.outer(d, d)))
    rms = {g.label: float(np.sqrt(np.mean(r[idx == i] ** 2))) for i, g in enumerate(groups)}
    return {"theta": theta, "cov": cov, "cov_iid": cov_iid, "sigma": dict(zip([g.label for g in groups], sigma.tolist())),
            "w": w, "inv": inv, "rms": rms, "cond": cond, "s2": s2, "n": n, "tau": tau,
            "inflation": float(np.max(np.sqrt(np.diag(cov) / np.maximum(np.diag(cov_iid), 1e-300))))}


def gain_covariance(groups: list[Group], Y: np.ndarray, w: np.ndarray, inv: np.ndarray, theta: np.ndarray,
                    gain_rel_std: Iterable[float]) -> np.ndarray:
    """Covariance of θ from independent relative drive-gain uncertainties (one per joint).

    A relative gain error ε_j multiplies every measured Δτ on joint j by (1 + ε_j), so
    ∂θ/∂ε_j = (YᵀWY)⁻¹·YᵀW·y_j with y_j the measured torques of joint j (0 elsewhere);
    the fitted model's prediction is used for y_j so that noise does not enter twice.
    """
    std = np.asarray(list(gain_rel_std), float)
    pred = Y @ theta
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    cov = np.zeros((len(theta), len(theta)))
    for j, sj in enumerate(std):
        if sj <= 0:
            continue
        rows = joint_of_row == j
        if not rows.any():
            continue
        dth = inv @ (Y[rows].T @ (w[rows] * pred[rows]))
        cov += sj ** 2 * np.outer(dth, dth)
    return cov


def length_parameters(kin: Kinematics) -> list[tuple[int, str]]:
    """The DH lengths whose uncertainty is propagated: every non-zero a_i and d_i, as (row, "a"|"d").

    Zero entries are structural (intersecting or coplanar axes by design) and taken as exact.
    """
    out = []
    for i, row in enumerate(kin.rows):
        if abs(row.a_m) > 0:
            out.append((i, "a"))
        if abs(row.d_m) > 0:
            out.append((i, "d"))
    return out


def _perturbed(kin: Kinematics, row: int, which: str, h: float) -> Kinematics:
    rows = list(kin.rows)
    r = rows[row]
    rows[row] = replace(r, a_m=r.a_m + h) if which == "a" else replace(r, d_m=r.d_m + h)
    return Kinematics(tuple(rows))


def length_derivatives(sweeps: list[DeltaSweep], kin: Kinematics, groups: list[Group]) -> list[np.ndarray]:
    """∂Y/∂p_k for every DH length of ``length_parameters(kin)``, rows stacked as in ``groups``.

    For fixed joint angles every position, hence every row of Y, is linear in the lengths, so one
    finite difference is exact up to rounding.
    """
    joints = tuple(sorted({g.joint for g in groups}))
    h = 1e-3
    out = []
    for row, which in length_parameters(kin):
        by_label = {g.label: g.Y for g in build_groups(sweeps, _perturbed(kin, row, which, h), joints)}
        out.append(np.vstack([(by_label[g.label] - g.Y) / h if g.label in by_label else -g.Y / h for g in groups]))
    return out


def absorbed_length_error(sweeps: list[DeltaSweep], groups: list[Group], dY: list[np.ndarray],
                          reference: tuple[Iterable[float], Iterable[int]]) -> dict[int, np.ndarray]:
    """Per calibrated joint j: ε_j·k, the relative gain change a calibration's fit made per unit error of length k.

    ε_jk = ⟨Y_j θ_ref, ∂Y_j/∂p_k θ_ref⟩ / ⟨Y_j θ_ref, Y_j θ_ref⟩ over joint j's rows of every sweep,
    each one-direction moving-joint group's mean removed from Y_j θ_ref (the calibration fits it an
    offset: friction the baseline left). The tool run's sweeps stand in for the calibration's
    (same procedure).
    """
    theta_ref = np.asarray(list(reference[0]), float)
    fitted = sorted(int(j) for j in reference[1])
    Y = np.vstack([g.Y for g in groups])
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    pred_ref = Y @ theta_ref
    one_way = {d.key.name: d.moving for d in sweeps if d.key.direction != "both"}
    centred = pred_ref.copy()
    start = 0
    for g in groups:
        sl = slice(start, start + len(g.y))
        if one_way.get(g.sweep, -1) == g.joint:
            centred[sl] -= np.mean(pred_ref[sl])
        start = sl.stop
    eps: dict[int, np.ndarray] = {}
    for j in fitted:
        rows = joint_of_row == j
        den = float(centred[rows] @ centred[rows]) if rows.any() else 0.0
        if den > 0:
            eps[j] = np.array([float(centred[rows] @ (d[rows] @ theta_ref)) / den for d in dY])
    return eps


def kinematic_sensitivities(sweeps: list[DeltaSweep], kin: Kinematics, groups: list[Group], w: np.ndarray,
                            inv: np.ndarray, theta: np.ndarray,
                            reference: tuple[Iterable[float], Iterable[int]] | None = None) -> np.ndarray:
    """∂θ̂/∂p_k for every DH length of ``length_parameters(kin)``: shape (K, 4), per metre.

    The regressor is evaluated with the nominal lengths p; the arm's torques follow the true ones,
    y = Y(p + δp)·θ. For fixed joint angles every position, hence every row of Y, is linear in
    the lengths, so ∂Y/∂p_k is exact from one finite difference, and to first order
    δθ̂ = Σ_k (YᵀWY)⁻¹·YᵀW·(∂Y/∂p_k·θ̂)·δp_k.

    ``reference`` = (θ_ref, fitted joints) of a drive-gain calibration made with the same
    kinematics on the same procedure, whose scales were applied to the data: its gain fit absorbed
    part of the same length error (joint j's scale became 1/(1 + Σ_k ε_jk·δp_k), with
    ε_jk = ⟨Y_j θ_ref, ∂Y_j/∂p_k θ_ref⟩ / ⟨Y_j θ_ref, Y_j θ_ref⟩ over joint j's rows, each
    group's mean removed from Y_j θ_ref where the calibration fits it an offset), so
    δθ̂ = Σ_k (YᵀWY)⁻¹·YᵀW·(∂Y/∂p_k·θ̂ − ε_·k ∘ Y·θ̂)·δp_k. The tool run's sweeps stand in for
    the calibration's (same procedure).
    """
    Y = np.vstack([g.Y for g in groups])
    pred = Y @ theta
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    dY = length_derivatives(sweeps, kin, groups)
    eps = absorbed_length_error(sweeps, groups, dY, reference) if reference is not None else {}
    out = []
    for k, d in enumerate(dY):
        v = d @ theta
        for j, e in eps.items():
            rows = joint_of_row == j
            v[rows] -= e[k] * pred[rows]
        out.append(inv @ (Y.T @ (w * v)))
    return np.array(out).reshape(-1, len(theta))


def kinematic_covariance(sweeps: list[DeltaSweep], kin: Kinematics, groups: list[Group], w: np.ndarray,
                         inv: np.ndarray, theta: np.ndarray, length_std_m: float,
                         reference: tuple[Iterable[float], Iterable[int]] | None = None) -> np.ndarray:
    """Covariance of θ from independent errors, standard uncertainty ``length_std_m`` each, of the
    non-zero DH lengths (``kinematic_sensitivities``): σ²·SᵀS."""
    if not length_std_m > 0:
        return np.zeros((len(theta), len(theta)))
    S = kinematic_sensitivities(sweeps, kin, groups, w, inv, theta, reference)
    return float(length_std_m) ** 2 * (S.T @ S)


def cog_with_covariance(theta: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c = θ[1:]/θ[0] and its 3×3 covariance (delta method)."""
    m = theta[0]
    c = theta[1:] / m
    J = np.zeros((3, 4))
    J[:, 0] = -theta[1:] / m ** 2
    J[:, 1:] = np.eye(3) / m
    return c, J @ cov @ J.T


def solve(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, poses: Iterable[str] | None = None,
          use_combined: bool = True, name: str = NAME, gain_rel_std: Iterable[float] | None = None,
          length_std_m: float | None = None,
          gain_reference: tuple[Iterable[float], Iterable[int]] | None = None) -> Estimate:
    """Weighted LS estimate of mass and centre of mass with its covariance (see the module docstring).

    ``gain_rel_std``: relative standard uncertainty of each joint's drive gain (0-based), e.g.
    a calibration's ``scale_std``; included in the reported uncertainty when given.
    ``length_std_m``: standard uncertainty of every non-zero DH length (``kinematic_covariance``);
    ``gain_reference``: (θ_ref = [m, m·cx, m·cy, m·cz], fitted joints) of the drive-gain calibration
    the data were scaled with, whose fit absorbed part of the length errors.
    """
    sweeps = select_sweeps(deltas, poses=poses, use_combined=use_combined)
    if not sweeps:
        which = "" if poses is None else f" in pose(s) {', '.join(sorted(poses))}"
        raise DataError(f"general: no sweep{which} to solve with")
    groups = build_groups(sweeps, kin)
    res = fit(groups, gain_rel_std)
    theta, cov = res["theta"], res["cov"]
    if length_std_m:
        cov = cov + kinematic_covariance(sweeps, kin, groups, res["w"], res["inv"], theta, length_std_m,
                                         gain_reference)
    mass = float(theta[0])
    if not mass > 0:
        raise DataError(f"general: identified mass {mass:.4f} kg is not positive; is a payload mounted?")
    c, cov_c = cog_with_covariance(theta, cov)
    notes = []
    if res["cond"] > 1e6:
        notes.append(f"the sweeps hardly observe every parameter (condition number {res['cond']:.3g}); "
                     "add a second tool orientation")
    combined = [d.key.name for d in sweeps if d.key.direction == "both"]
    if combined:
        notes.append(f"bidirectional (friction-cancelling) sweeps used: {', '.join(combined)}")
    return Estimate(
        solver=name,
        mass_kg=mass,
        cog_m=(float(c[0]), float(c[1]), float(c[2])),
        residual_rms_nm=res["rms"],
        samples={d.key.name: len(d.q) for d in sweeps},
        mass_std_kg=float(np.sqrt(max(cov[0, 0], 0.0))),
        cog_std_m=tuple(float(np.sqrt(max(v, 0.0))) for v in np.diag(cov_c)),
        covariance=cov.tolist(),
        condition_number=res["cond"],
        notes=notes,
    )
