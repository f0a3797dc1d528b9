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

Weights and covariance: ``payload_agent.solvers.wls.fit`` (two passes, weights 1/σ² per
(sweep, joint) group, autocorrelation-robust sandwich covariance, never below the
independent-noise one). An optional relative drive-gain uncertainty per joint (from
``payload-agent calibrate``) is
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

from dataclasses import replace
from typing import Iterable

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import SweepKey
from payload_agent.solvers.fitted import FittedModel
from payload_agent.solvers import length_response
from payload_agent.solvers.regressor import payload_regressor
from payload_agent.solvers.results import Estimate
from payload_agent.solvers.wls import Group, cog_with_covariance

NAME = "general"
GRAVITY_JOINTS = (1, 2, 3, 4, 5)  # 0-based: joints 2..6
ZERO_ROW_TOL = 1e-9  # N·m per unit θ: a joint whose rows are all below this carries no payload torque
__all__ = ["NAME", "GRAVITY_JOINTS", "ZERO_ROW_TOL", "select_sweeps", "build_groups", "length_parameters",
           "perturbed", "length_derivatives", "absorbed_length_error", "stands_apart", "angle_derivatives", "length_absorption",
           "kinematic_sensitivities",
           "kinematic_covariance", "fit_model", "model_length_derivatives", "solve", "estimate"]


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


def build_groups(sweeps: list[DeltaSweep], kin: Kinematics,
                 joints: Iterable[int] = GRAVITY_JOINTS) -> list[Group]:
    joints = tuple(joints)
    groups = []
    # vectorised: the payload's Newton–Euler regressor at constant speed of the moving joint,
    # first four columns, is exactly regressor() (gravity + centripetal), ~500x faster per sweep
    for d in sweeps:
        qd = np.zeros_like(d.q)
        qd[:, d.moving] = d.speed_rad_s
        Y = payload_regressor(kin, d.q, qd, np.zeros_like(d.q), inertia=False)[:, list(joints)]  # (n, len(joints), 4)
        for c, j in enumerate(joints):
            Yj = Y[:, c, :]
            if np.max(np.abs(Yj)) < ZERO_ROW_TOL:
                continue
            groups.append(Group(f"{d.key.name}/j{j + 1}", d.key.name, Yj, np.asarray(d.dtau[:, j], float), j,
                                d.noise_map))
    return groups


def stands_apart(sweeps: list[DeltaSweep], groups: list[Group]) -> list[bool]:
    """Per group: True where its joint stands still in its sweep and moves in another of ``sweeps``.

    A drive-gain calibration fits each such group a scale of its own (``gain_scales``, ``zero_offsets``), so the
    joint's drive gain comes from its moving rows alone. Why: a strain-wave gear's load-dependent mesh ripple is,
    on a joint that stands, a torque-gain error of that one angle (the mesh phase is frozen, nothing averages it;
    docs/benchmarks.md, "Session 24"); read as the drive's gain it is carried to every angle the joint turns
    through, where the mesh ripple does average out."""
    by_name = {d.key.name: d for d in sweeps}
    moves = {g.joint for g in groups if by_name[g.sweep].moving == g.joint}
    return [by_name[g.sweep].moving != g.joint and g.joint in moves for g in groups]


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


def perturbed(kin: Kinematics, row: int, which: str, h: float) -> Kinematics:
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
        by_label = {g.label: g.Y for g in build_groups(sweeps, perturbed(kin, row, which, h), joints)}
        out.append(np.vstack([(by_label[g.label] - g.Y) / h if g.label in by_label else -g.Y / h for g in groups]))
    return out


def absorbed_length_error(sweeps: list[DeltaSweep], groups: list[Group], dY: list[np.ndarray],
                          reference: tuple[Iterable[float], Iterable[int]]) -> dict[int, np.ndarray]:
    """Per calibrated joint j: ε_j·k, the relative gain change a calibration's fit made per unit error of length k.

    ε_jk = ⟨Y_j θ_ref, ∂Y_j/∂p_k θ_ref⟩ / ⟨Y_j θ_ref, Y_j θ_ref⟩ over joint j's rows of every sweep,
    each one-direction moving-joint group's mean removed from Y_j θ_ref (the calibration fits it an
    offset: friction the baseline left), and the groups where joint j stands while it moves in another sweep
    left out (the calibration fits each its own scale, ``stands_apart``). The tool run's sweeps stand in for the
    calibration's (same procedure).
    """
    theta_ref = np.asarray(list(reference[0]), float)
    fitted = sorted(int(j) for j in reference[1])
    Y = np.vstack([g.Y for g in groups])
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    pred_ref = Y @ theta_ref
    one_way = {d.key.name: d.moving for d in sweeps if d.key.direction != "both"}
    centred = pred_ref.copy()
    start = 0
    for g, apart in zip(groups, stands_apart(sweeps, groups)):
        sl = slice(start, start + len(g.y))
        if apart:  # the calibration fits this group its own scale: it takes no part in the joint's gain
            centred[sl] = 0.0
        elif one_way.get(g.sweep, -1) == g.joint:
            centred[sl] -= np.mean(pred_ref[sl])
        start = sl.stop
    eps: dict[int, np.ndarray] = {}
    for j in fitted:
        rows = joint_of_row == j
        den = float(centred[rows] @ centred[rows]) if rows.any() else 0.0
        if den > 0:
            eps[j] = np.array([float(centred[rows] @ (d[rows] @ theta_ref)) / den for d in dY])
    return eps


ANGLE_STEP_RAD = 1e-4  # finite step of ∂(Yθ)/∂q_i (as ``zero_offsets``): small against the levers, large against rounding


def angle_derivatives(sweeps: list[DeltaSweep], kin: Kinematics, groups: list[Group], theta: np.ndarray,
                      joints: Iterable[int]) -> dict[int, np.ndarray]:
    """∂(Y·θ)/∂q_i over ``groups``' stacked rows for each joint i of ``joints`` (one finite difference)."""
    base = np.concatenate([g.Y @ theta for g in groups])
    rows = tuple(sorted({g.joint for g in groups}))
    out = {}
    for i in joints:
        shifted = {g.label: g.Y for g in build_groups([replace(d, q=d.q + np.eye(d.q.shape[1])[i] * ANGLE_STEP_RAD)
                                                        for d in sweeps], kin, rows)}
        moved = np.concatenate([shifted[g.label] @ theta if g.label in shifted else np.zeros(len(g.y)) for g in groups])
        out[i] = (moved - base) / ANGLE_STEP_RAD
    return out


def length_absorption(sweeps: list[DeltaSweep], kin: Kinematics, groups: list[Group], theta: np.ndarray,
                      dY: list[np.ndarray], reference: tuple | None) -> list[np.ndarray] | None:
    """Per DH length: what the drive-gain calibration the data were scaled (and their angles corrected) with
    adds to the run's rows per metre of its error, or None without a calibration.

    The calibration's own measured response (``length_response``, stored since it is measured) where the
    reference carries one; else the older rule (``absorbed_length_error``: the tool run's sweeps standing in for
    the calibration's, right only for a calibration on the same procedure; its zeros not counted)."""
    if reference is None:
        return None
    measured = length_response.of_reference(reference)
    if measured is not None:
        dq = angle_derivatives(sweeps, kin, groups, theta, length_response.zero_joints(measured))
        return length_response.extra_rows(measured, length_parameters(kin), groups, theta, dq)
    eps = absorbed_length_error(sweeps, groups, dY, reference)
    pred = np.concatenate([g.Y @ theta for g in groups])
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    out = []
    for k in range(len(dY)):
        v = np.zeros(len(pred))
        for j, e in eps.items():
            rows = joint_of_row == j
            v[rows] -= e[k] * pred[rows]
        out.append(v)
    return out


def kinematic_sensitivities(sweeps: list[DeltaSweep], kin: Kinematics, groups: list[Group], w: np.ndarray,
                            inv: np.ndarray, theta: np.ndarray,
                            reference: tuple[Iterable[float], Iterable[int]] | None = None,
                            dY: list[np.ndarray] | None = None) -> np.ndarray:
    """∂θ̂/∂p_k for every DH length of ``length_parameters(kin)``: shape (K, 4), per metre.

    The regressor is evaluated with the nominal lengths p; the arm's torques follow the true ones,
    y = Y(p + δp)·θ. For fixed joint angles every position, hence every row of Y, is linear in
    the lengths, so ∂Y/∂p_k is exact from one finite difference, and to first order
    δθ̂ = Σ_k (YᵀWY)⁻¹·YᵀW·(∂Y/∂p_k·θ̂)·δp_k.

    ``reference`` = (θ_ref, fitted joints) of a drive-gain calibration made with the same
    kinematics, whose scales were applied to the data: its gain fit absorbed
    part of the same length error (joint j's scale became 1/(1 + Σ_k ε_jk·δp_k), with
    ε_jk = ⟨Y_j θ_ref, ∂Y_j/∂p_k θ_ref⟩ / ⟨Y_j θ_ref, Y_j θ_ref⟩ over joint j's rows, each
    group's mean removed from Y_j θ_ref where the calibration fits it an offset), so
    δθ̂ = Σ_k (YᵀWY)⁻¹·YᵀW·(∂Y/∂p_k·θ̂ − ε_·k ∘ Y·θ̂)·δp_k. ``length_absorption``: the calibration's
    own measured response to each length (its scales and zeros) where it stored one, else that older rule with
    the tool run's sweeps standing in for the calibration's. ``dY``: ``length_derivatives`` when already computed.
    """
    Y = np.vstack([g.Y for g in groups])
    dY = length_derivatives(sweeps, kin, groups) if dY is None else dY
    extra = length_absorption(sweeps, kin, groups, theta, dY, reference)
    out = []
    for k, d in enumerate(dY):
        v = d @ theta if extra is None else d @ theta + extra[k]
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


def fit_model(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, gain_rel_std: Iterable[float] | None = None, *,
              poses: Iterable[str] | None = None, use_combined: bool = True) -> FittedModel:
    """The one fitted model of these deltas (``solvers.fitted``): rows built here, each fit made when first used.

    ``gain_rel_std``: relative drive-gain uncertainty per joint (0-based), part of ``cov_params()``.
    """
    sweeps = select_sweeps(deltas, poses=poses, use_combined=use_combined)
    return FittedModel(deltas, kin, tuple(sweeps), tuple(build_groups(sweeps, kin)), {d.key.name: d.key.pose for d in sweeps},
                       None if gain_rel_std is None else tuple(float(v) for v in gain_rel_std))


def model_length_derivatives(model: FittedModel) -> list[np.ndarray]:
    """``length_derivatives`` of the model's rows, computed once per model."""
    return model.cached(("length derivatives",),
                        lambda: length_derivatives(list(model.sweeps), model.kin, list(model.groups)))


def solve(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, poses: Iterable[str] | None = None,
          use_combined: bool = True, name: str = NAME, gain_rel_std: Iterable[float] | None = None,
          length_std_m: float | None = None,
          gain_reference: tuple[Iterable[float], Iterable[int]] | None = None,
          model: FittedModel | None = None) -> Estimate:
    """Weighted LS estimate of mass and centre of mass with its covariance (see the module docstring).

    ``gain_rel_std``: relative standard uncertainty of each joint's drive gain (0-based), e.g.
    a calibration's ``scale_std``; included in the reported uncertainty when given.
    ``length_std_m``: standard uncertainty of every non-zero DH length (``kinematic_covariance``);
    ``gain_reference``: (θ_ref = [m, m·cx, m·cy, m·cz], fitted joints) of the drive-gain calibration
    the data were scaled with, whose fit absorbed part of the length errors.
    ``model``: the analysis' fitted model of ``deltas`` with ``gain_rel_std`` (``fit_model``), made here if None.
    """
    if model is None:
        model = fit_model(deltas, kin, gain_rel_std, poses=poses, use_combined=use_combined)
    return estimate(model, name=name, length_std_m=length_std_m, gain_reference=gain_reference, poses=poses)


def estimate(model: FittedModel, *, name: str = NAME, length_std_m: float | None = None,
             gain_reference: tuple[Iterable[float], Iterable[int]] | None = None,
             poses: Iterable[str] | None = None) -> Estimate:
    """The general solver's estimate from a fitted model: θ, ``cov_params()`` and the DH-length term
    (``poses``: only to name them when the model has no sweep)."""
    sweeps = list(model.sweeps)
    if not sweeps:
        which = "" if poses is None else f" in pose(s) {', '.join(sorted(poses))}"
        raise DataError(f"general: no sweep{which} to solve with")
    res = model.fit()
    theta, cov = res.theta, model.cov_params()
    if length_std_m and length_std_m > 0:
        S = kinematic_sensitivities(sweeps, model.kin, list(model.groups), res.weights, res.normal_inverse, theta,
                                    gain_reference, dY=model_length_derivatives(model))
        cov = cov + float(length_std_m) ** 2 * (S.T @ S)
    mass = float(theta[0])
    if not mass > 0:
        raise DataError(f"general: identified mass {mass:.4f} kg is not positive; is a payload mounted?")
    c, cov_c = cog_with_covariance(theta, cov)
    notes = []
    if res.condition_number > 1e6:
        notes.append(f"the sweeps hardly observe every parameter (condition number {res.condition_number:.3g}); "
                     "add a second tool orientation")
    if length_std_m and length_std_m > 0 and gain_reference is not None \
            and length_response.of_reference(gain_reference) is None:
        notes.append("DH-length term: the drive-gain calibration predates its measured response to the lengths, so "
                     "its absorption is estimated on this run's sweeps (right only if it swept the same procedure; "
                     "its zeros not counted); calibrate again to measure it")
    combined = [d.key.name for d in sweeps if d.key.direction == "both"]
    if combined:
        notes.append(f"bidirectional (friction-cancelling) sweeps used: {', '.join(combined)}")
    return Estimate(
        solver=name,
        mass_kg=mass,
        cog_m=(float(c[0]), float(c[1]), float(c[2])),
        residual_rms_nm=res.residual_rms_nm,
        samples={d.key.name: len(d.q) for d in sweeps},
        mass_std_kg=float(np.sqrt(max(cov[0, 0], 0.0))),
        cog_std_m=tuple(float(np.sqrt(max(v, 0.0))) for v in np.diag(cov_c)),
        covariance=cov,
        condition_number=res.condition_number,
        notes=notes,
    )
