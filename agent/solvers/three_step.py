"""The paper's three-step solver (Gao, Zhao, Li 2025, eqs. 23-25), lever geometry from FK.

1. mass from pose b: Δτ2(θ) − Δτ3(θ) = m·φ(θ), with Δτ2 from the joint-2 sweep and
   Δτ3 from the joint-3 sweep at the same link elevation θ (eq. 23); φ is the lever
   between the joint-2 and joint-3 axes, g·a2·cos θ for an ideal arm, taken from FK here;
2. x and y from joint 3 in pose b (eq. 24);
3. z from joint 3 in pose d with m, x (and y) known (eq. 25).
In each step the paper's cos θ/sin θ coefficients, and its a3+d5 and a3+d6 lever terms,
are the exact gravity-lever terms of the regressor Y(q) evaluated on the DH model, so the
signs and offsets follow whatever conventions the robot uses.

Directions: where a sweep was recorded both ways, the friction-cancelling combination
(direction "both", ``payload_agent.analysis.combine``) is used, as the general solver does;
otherwise the upward sweep, as published. With load-dependent friction the upward sweep
alone biases the mass by a fraction of the load ratio (the paper's own explanation of its
errors growing with mass).

Uncertainty: every estimate is a function of the three sweeps' Δτ samples, so its first-order
sensitivity to each sample (``_jacobians``: through the step-1 interpolation, and through m
into steps 2 and 3, and through x, y into step 3) times that sweep's residuals gives scores
whose long-run variance (Bartlett kernel, bandwidth from the residuals' autocorrelation time,
as in ``solvers.wls``; where the deltas carry their noise maps, the map's at every lag, scaled up where the
kernel shows more, ``wls.modelled_excess``) is the covariance of [m, x, y, z]; never below the independent-noise
value. An optional relative drive-gain uncertainty of joints 2 and 3 is propagated on top, and the DH lengths'
uncertainty by re-running the steps with each length moved, less what a drive-gain calibration absorbed of it
(``length_covariance``, the general solver's DH-length term through the three steps). Where a drive-gain calibration
subtracted the same empty run, the analysis adds that run's noise correlation between the two (``scores``, the
steps' first-order map, through ``evaluation.shared_baseline``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.arm_geometry import ArmGeometry, wrap
from payload_agent.model.kinematics import GRAVITY_M_S2, Kinematics
from payload_agent.solvers.regressor import chain_frames, payload_regressor
from payload_agent.solvers.results import Estimate
from payload_agent.solvers.wls import (HAC_MAX_FRACTION, autocorrelation_time, long_run_scores, modelled_excess,
                                      line_leftover, without_lines)
from payload_agent.types import SweepKey

NAME = "three-step"
PREFERENCE = ("both", "up")  # combined where recorded both ways, else the published upward sweep
LENGTH_STEP_M = 1e-4  # the finite step of a DH length (the steps are smooth in it: levers and the 1/m of steps 2, 3)
GAIN_STEP = 1e-4  # the finite step of a relative drive-gain error


def _find(deltas: dict[SweepKey, DeltaSweep], pose: str, joint: int,
          directions: tuple[str, ...] = PREFERENCE) -> DeltaSweep:
    for direction in directions:
        for key, d in deltas.items():
            if key.pose == pose and key.joint == joint and key.direction == direction:
                return d
    raise DataError(f"three-step needs the joint-{joint} sweep in pose {pose} "
                    f"({' or '.join(directions)}), which the run does not have")


def _lever_terms(kin: Kinematics, q: np.ndarray, joint_index: int) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) per sample with Δτ_j = m·A + m·B·c: A from the flange position, B from its rotation."""
    rows = payload_regressor(kin, q, np.zeros_like(q), np.zeros_like(q), inertia=False)[:, joint_index]
    return rows[:, 0], rows[:, 1:]


def _axis_lever(kin: Kinematics, q: np.ndarray) -> np.ndarray:
    """φ = z2·((o3 − o2) × g⃗): the weight's lever between the joint-2 and joint-3 axes (g·a2·cos θ)."""
    frames = chain_frames(kin, q)
    z2, o2, o3 = frames[1][:, :3, 2], frames[1][:, :3, 3], frames[2][:, :3, 3]
    return np.einsum("ni,ni->n", z2, np.cross(o3 - o2, np.array([0.0, 0.0, GRAVITY_M_S2])))


def _link3_elevation(geo: ArmGeometry, q: np.ndarray) -> np.ndarray:
    """Link 3's elevation above horizontal per sample: affine in (q2, q3), slopes measured on the model."""
    q2, q3 = q[0, 1], q[0, 2]
    e0 = geo.elevations(q2, q3)[1]
    d = 0.1
    a = wrap(geo.elevations(q2 + d, q3)[1] - e0) / d
    b = wrap(geo.elevations(q2, q3 + d)[1] - e0) / d
    return e0 + a * (q[:, 1] - q2) + b * (q[:, 2] - q3)


def _interp_transpose(x_new: np.ndarray, xs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Pᵀ·weights for the linear interpolation P (P @ ys == np.interp(x_new, xs, ys), xs ascending)."""
    k = np.clip(np.searchsorted(xs, x_new, side="right") - 1, 0, len(xs) - 2)
    span = xs[k + 1] - xs[k]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(span > 0, (x_new - xs[k]) / span, 0.0)
    out = np.zeros(len(xs))
    np.add.at(out, k, (1.0 - f) * weights)
    np.add.at(out, k + 1, f * weights)
    return out


@dataclass(frozen=True)
class Scores:
    """The three steps' first-order map from the Δτ samples they read to β = [m, x, y, z]: what a term that acts on
    those samples through a linear estimator needs (``evaluation.shared_baseline``: the empty run's noise, shared
    with a drive-gain calibration)."""

    beta: np.ndarray  # (4,) β = [m, x, y, z]
    rows: dict[tuple[str, int], np.ndarray]  # (sweep name, 0-based joint) -> ∂β/∂(those Δτ samples), (4, n)
    gain_response: dict[int, np.ndarray]  # 0-based joint -> ∂β/∂(a relative gain error of that joint), (4,)


@dataclass(frozen=True)
class _Steps:
    """One solution of the three steps and what its covariance is made from."""

    sweeps: dict[str, DeltaSweep]  # "b2", "b3", "d3"
    beta: np.ndarray
    J: dict[str, np.ndarray]  # sweep -> ∂β/∂Δτ samples (``_jacobians``)
    data: dict[str, tuple[np.ndarray, np.ndarray, int]]  # sweep -> (measured Δτ, prediction, joint index)
    residual_rms_nm: dict[str, float]
    samples: dict[str, int]


def _steps(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, pose_xy: str, pose_z: str,
           directions: tuple[str, ...]) -> _Steps:
    """The paper's three steps (module docstring) and their first-order sensitivities."""
    b2, b3, d3 = (_find(deltas, pose_xy, 2, directions), _find(deltas, pose_xy, 3, directions),
                  _find(deltas, pose_z, 3, directions))
    geo = ArmGeometry(kin, float(np.median(b2.q[:, 0])))

    # step 1 (eq. 23): pair joint-2 samples with the joint-3 sweep at the same link elevation
    elev_b2, elev_b3 = _link3_elevation(geo, b2.q), _link3_elevation(geo, b3.q)
    order = np.argsort(elev_b3)
    xs, ys = elev_b3[order], b3.dtau[order, 2]
    inside = (elev_b2 >= xs[0]) & (elev_b2 <= xs[-1])
    if inside.sum() < 10:
        raise DataError(f"three-step: the joint-2 and joint-3 sweeps of pose {pose_xy} share too few link "
                        f"elevations ({inside.sum()} samples)")
    phi = _axis_lever(kin, b2.q[inside])
    delta = b2.dtau[inside, 1] - np.interp(elev_b2[inside], xs, ys)
    mass = float(phi @ delta / (phi @ phi))
    if not mass > 0:
        raise DataError(f"three-step: identified mass {mass:.4f} kg is not positive; is a payload mounted?")
    res1 = delta - mass * phi

    # step 2 (eq. 24): [cos θ, sin θ]·[x, y] = Δτ3/(m g) − (a3 + d5) cos θ, from joint 3 in pose b
    A3, B3 = _lever_terms(kin, b3.q, 2)
    rhs = b3.dtau[:, 2] / mass - A3
    xy, *_ = np.linalg.lstsq(B3[:, :2], rhs, rcond=None)
    res2 = mass * (B3[:, :2] @ xy - rhs)

    # step 3 (eq. 25): z cos θ = Δτ3/(m g) − (a3 + d6) cos θ − (x + l_s) sin θ, from joint 3 in pose d
    Ad, Bd = _lever_terms(kin, d3.q, 2)
    rhs = d3.dtau[:, 2] / mass - Ad - Bd[:, :2] @ xy
    z = float(Bd[:, 2] @ rhs / (Bd[:, 2] @ Bd[:, 2]))
    res3 = mass * (Bd[:, 2] * z - rhs)

    beta = np.array([mass, float(xy[0]), float(xy[1]), z])
    c = beta[1:]
    A2, B2 = _lever_terms(kin, b2.q, 1)
    dm_dv = np.zeros(len(xs))  # ∂m/∂(b3's Δτ3), back in the b3 sweep's own sample order
    dm_dv[order] = -_interp_transpose(elev_b2[inside], xs, phi) / float(phi @ phi)
    data = {  # sweep -> (measured Δτ, the three-step model's prediction, joint index)
        "b2": (b2.dtau[:, 1], mass * (A2 + B2 @ c), 1),
        "b3": (b3.dtau[:, 2], mass * (A3 + B3 @ c), 2),
        "d3": (d3.dtau[:, 2], mass * (Ad + Bd @ c), 2),
    }
    J = _jacobians(beta, phi, inside, dm_dv, B3, Bd, data["b3"][0], d3.dtau[:, 2])

    def rms(r):
        return float(np.sqrt(np.mean(r ** 2)))

    return _Steps({"b2": b2, "b3": b3, "d3": d3}, beta, J, data,
                  {f"{pose_xy}-j2/j3 (mass)": rms(res1), f"{b3.key.name} (x, y)": rms(res2),
                   f"{d3.key.name} (z)": rms(res3)},
                  {b2.key.name: int(inside.sum()), b3.key.name: len(b3.q), d3.key.name: len(d3.q)})


def scores(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, pose_xy: str = "b", pose_z: str = "d",
           directions: tuple[str, ...] = PREFERENCE) -> Scores:
    """The three steps' ``Scores`` on these deltas (the same steps ``solve`` takes with the same options)."""
    s = _steps(deltas, kin, pose_xy, pose_z, directions)
    rows = {(s.sweeps[k].key.name, s.data[k][2]): s.J[k] for k in s.J}
    return Scores(s.beta, rows, _gain_responses(s.J, s.data))


def theta_jacobian(beta: np.ndarray) -> np.ndarray:
    """∂θ/∂β for θ = [m, m·c] and β = [m, c]: the covariance of β to the θ the other solvers report."""
    mass, c = float(beta[0]), np.asarray(beta[1:], float)
    Jt = np.zeros((4, 4))
    Jt[0, 0] = 1.0
    Jt[1:, 0] = c
    Jt[1:, 1:] = mass * np.eye(3)
    return Jt


def solve(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, pose_xy: str = "b", pose_z: str = "d",
          directions: tuple[str, ...] = PREFERENCE, gain_rel_std: Iterable[float] | None = None,
          length_std_m: float | None = None, gain_reference: object = None, model: object = None) -> Estimate:
    """Mass and centre of mass by the paper's three steps, with the covariance of the result.

    ``directions``: which recorded direction to use per sweep, in order of preference (default:
    the combined "both", else "up"; ``("up",)`` is the paper's single-direction procedure).
    ``gain_rel_std``: relative standard uncertainty of each joint's drive gain (0-based), added
    to the covariance for joints 2 and 3. ``length_std_m``: standard uncertainty of every non-zero DH length,
    added through the three steps (``length_covariance``; ``gain_reference``, (θ_ref, fitted joints) of the
    drive-gain calibration the data were scaled with, absorbed part of it; ``model``: the analysis' fitted model,
    whose rows name where).
    """
    s = _steps(deltas, kin, pose_xy, pose_z, directions)
    beta = s.beta
    maps = {name: d.noise_map for name, d in s.sweeps.items()}
    cov_beta = _covariance(s.J, s.data, gain_rel_std, maps)
    if length_std_m is not None and length_std_m > 0:
        cov_beta = cov_beta + length_covariance(deltas, kin, beta, float(length_std_m), gain_reference, model,
                                                dict(pose_xy=pose_xy, pose_z=pose_z, directions=directions))
    Jt = theta_jacobian(beta)  # θ = [m, m·c]: the covariance the other solvers report
    cov_theta = Jt @ cov_beta @ Jt.T
    std = np.sqrt(np.maximum(np.diag(cov_beta), 0.0))

    b2, b3, d3 = s.sweeps["b2"], s.sweeps["b3"], s.sweeps["d3"]
    used = sorted({d.key.direction for d in (b2, b3, d3)})
    notes = [f"three-step on {', '.join(d.key.name for d in (b2, b3, d3))}"
             + (" (bidirectional, friction-cancelling)" if used == ["both"] else "")]
    return Estimate(
        solver=NAME,
        mass_kg=float(beta[0]),
        cog_m=(float(beta[1]), float(beta[2]), float(beta[3])),
        residual_rms_nm=s.residual_rms_nm,
        samples=s.samples,
        mass_std_kg=float(std[0]),
        cog_std_m=(float(std[1]), float(std[2]), float(std[3])),
        covariance=cov_theta,
        notes=notes,
    )


def length_covariance(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, beta: np.ndarray, length_std_m: float,
                      gain_reference: object = None, model: object = None, steps: dict | None = None) -> np.ndarray:
    """Covariance of β = [m, x, y, z] from independent errors, standard uncertainty ``length_std_m`` each, of the
    non-zero DH lengths (``general.length_parameters``): the general solver's DH-length term
    (``general.kinematic_sensitivities``) through the three steps instead of the weighted fit: σ²·DᵀD with D of
    ``length_sensitivities``."""
    D = length_sensitivities(deltas, kin, beta, gain_reference, model, steps)
    return float(length_std_m) ** 2 * (D.T @ D)


def length_sensitivities(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, beta: np.ndarray,
                         gain_reference: object = None, model: object = None, steps: dict | None = None) -> np.ndarray:
    """(K, 4): β̂'s error per metre of error of each DH length of ``general.length_parameters(kin)``.

    The arm's torques follow the true lengths p + δp while the steps' levers use the nominal p; the steps are
    consistent (right lengths, right β), so β̂'s error is −∂β̂/∂p_k·δp_k, by re-running them with one length
    moved.
    A drive-gain calibration the data were scaled and corrected with (``gain_reference`` = (θ_ref, fitted
    joints, ...)) moved its gains and zeros with the same length errors. Where it stored its measured response
    (``length_response``): joint j's relative scale change r_jk adds r_jk·∂β̂/∂g_j (g_j: a relative gain error of
    joint j on every sweep; the steps read joints 2 and 3) and its zero change ζ_ik adds −ζ_ik·∂β̂/∂q_i (the
    corrected angles q − z move by −δz). Else the older rule: on the same procedure it absorbed the share
    ε_jk·δp_k into joint j's gain (``general.absorbed_length_error``): −ε_jk·∂β̂/∂g_j."""
    from dataclasses import replace

    from payload_agent.solvers import general, length_response

    def beta_of(d: dict[SweepKey, DeltaSweep], k: Kinematics) -> np.ndarray:
        e = solve(d, k, **(steps or {}))
        return np.array([e.mass_kg, *e.cog_m])

    params = general.length_parameters(kin)
    if not params:
        return np.zeros((0, 4))
    D = np.array([-(beta_of(deltas, general.perturbed(kin, row, which, LENGTH_STEP_M)) - beta) / LENGTH_STEP_M
                  for row, which in params])  # (K, 4)

    def gain_step(j: int) -> np.ndarray:  # ∂β̂/∂g_j
        shifted = {}
        for key, d in deltas.items():
            dtau = np.array(d.dtau, float)
            dtau[:, j] *= 1.0 + GAIN_STEP
            shifted[key] = replace(d, dtau=dtau)
        return (beta_of(shifted, kin) - beta) / GAIN_STEP

    measured = length_response.of_reference(gain_reference)  # type: ignore[arg-type]
    if measured is not None:
        if tuple(params) != measured.lengths:
            raise ValueError(f"the calibration's length response is for DH lengths {measured.lengths}, "
                             f"the kinematics has {tuple(params)}")
        scale, zero = np.array(measured.scale_rel_per_m), np.array(measured.zero_rad_per_m)
        for j in (1, 2):  # joints 2 and 3: the only rows the steps read
            if np.any(scale[:, j] != 0):
                D += np.outer(scale[:, j], gain_step(j))
        for i in length_response.zero_joints(measured):
            moved = {key: replace(d, q=np.asarray(d.q, float) + np.eye(6)[i] * general.ANGLE_STEP_RAD)
                     for key, d in deltas.items()}
            D -= np.outer(zero[:, i], (beta_of(moved, kin) - beta) / general.ANGLE_STEP_RAD)
        return D
    if gain_reference is not None:
        if model is None:
            model = general.fit_model(deltas, kin)  # the rows only: no fit is made here
        sweeps, groups = list(model.sweeps), list(model.groups)  # type: ignore[attr-defined]
        dY = general.model_length_derivatives(model)  # type: ignore[arg-type]
        eps = general.absorbed_length_error(sweeps, [replace(g, Y=g.Y[:, :4]) for g in groups],
                                            [d[:, :4] for d in dY], gain_reference)  # type: ignore[arg-type]
        for j in sorted(set(eps) & {1, 2}):  # joints 2 and 3: the only rows the steps read
            D -= np.outer(eps[j], gain_step(j))
    return D


def _jacobians(beta: np.ndarray, phi: np.ndarray, inside: np.ndarray, dm_dv: np.ndarray, B3: np.ndarray,
               Bd: np.ndarray, v: np.ndarray, w: np.ndarray) -> dict[str, np.ndarray]:
    """∂[m, x, y, z]/∂(each sweep's Δτ samples): 4 × n per sweep (b2 joint 2, b3 joint 3, d3 joint 3).

    ``dm_dv``: ∂m/∂v through the step-1 interpolation of the b3 sweep (−Pᵀφ/φᵀφ).
    """
    m = beta[0]
    dm_du = np.zeros(len(inside))
    dm_du[inside] = phi / float(phi @ phi)
    G = np.linalg.pinv(B3[:, :2])  # xy = G·(v/m − A3)
    dxy_dm = -(G @ v) / m ** 2
    dxy_dv = G / m + np.outer(dxy_dm, dm_dv)
    dxy_du = np.outer(dxy_dm, dm_du)
    bz = Bd[:, 2]
    Z = float(bz @ bz)
    dz_dm = -float(bz @ w) / (m ** 2 * Z)
    dz_dxy = -(bz @ Bd[:, :2]) / Z
    out = {}
    for name, dm, dxy in (("b2", dm_du, dxy_du), ("b3", dm_dv, dxy_dv)):
        out[name] = np.vstack([dm, dxy, dz_dm * dm + dz_dxy @ dxy])
    Jd = np.zeros((4, len(w)))
    Jd[3] = bz / (m * Z)
    out["d3"] = Jd
    return out


def _covariance(J: dict[str, np.ndarray], data: dict[str, tuple[np.ndarray, np.ndarray, int]],
                gain_rel_std: Iterable[float] | None, noise_maps: dict | None = None) -> np.ndarray:
    """Σ over sweeps of the long-run variance of the scores J_s·r_s, floored at the independent-noise value.

    Where a sweep's noise map says how its samples' noise is made (``DeltaSweep.noise_map``: the empty run and the
    legs interpolated onto the combined grid), the long-run variance is the map's at every lag, scaled up where the
    residuals' kernel estimate shows more (``wls.modelled_excess``, as the general solver): the Bartlett kernel
    alone down-weights the neighbouring samples' shared interpolation error and ran 3–7 % low in σ, most on the
    CoM y (docs/benchmarks.md, "Session 17")."""
    cov = np.zeros((4, 4))
    cov_iid = np.zeros((4, 4))
    for name, Js in J.items():
        meas, pred, _ = data[name]
        r, lines = without_lines(meas - pred)  # the noise: no mesh ripple that averages out of the steps (``wls``)
        cov += line_leftover(Js.T, lines)  # what the ripple does leave in the steps
        n = len(r)
        _, lag = autocorrelation_time(r, max_lag=max(1, int(HAC_MAX_FRACTION * n)))
        dof = n / max(n - 1, 1)
        B = long_run_scores(Js.T * r[:, None], lag) * dof
        noise = None if noise_maps is None else noise_maps.get(name)
        if noise is not None and noise.shape[0] == n:
            B = modelled_excess(B, noise, lag, [(Js.T, float(np.mean(r ** 2)) * dof)])
        cov += B
        cov_iid += float(np.mean(r ** 2)) * dof * (Js @ Js.T)
    ratio = np.sqrt(np.maximum(np.diag(cov), 0.0) / np.maximum(np.diag(cov_iid), 1e-300))
    if np.any(ratio < 1.0):
        f = np.sqrt(np.maximum(1.0 / ratio, 1.0))
        cov = cov * np.outer(f, f)
    if gain_rel_std is not None:
        std = np.asarray(list(gain_rel_std), float)
        for j, g in _gain_responses(J, data).items():
            if j < len(std) and std[j] > 0:
                cov += std[j] ** 2 * np.outer(g, g)
    return cov


def _gain_responses(J: dict[str, np.ndarray], data: dict[str, tuple[np.ndarray, np.ndarray, int]]
                    ) -> dict[int, np.ndarray]:
    """∂β/∂(a relative gain error of joint j) per joint read, to first order: Σ over its sweeps of J·prediction."""
    out: dict[int, np.ndarray] = {}
    for name, Js in J.items():
        j = data[name][2]
        out[j] = out.get(j, np.zeros(4)) + Js @ data[name][1]
    return out
