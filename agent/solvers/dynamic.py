"""Dynamic-model baseline: payload inertial parameters from an excitation trajectory (paper §3.4, eq. 29).

The comparison method of Gao, Zhao and Li (2025, §3.4, after Khalil, Gautier and Lemoine
2007): drive the arm twice along the same excitation trajectory, once with an empty flange
and once with the payload, and solve

    τ_load − τ_empty = W(q, q̇, q̈) · H_load                                     (eq. 29)

by least squares. The arm's own dynamics cancel in the difference; what remains is the
payload's contribution, which is linear in its ten inertial parameters

    θ = [m, m·cx, m·cy, m·cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]

(first moments and inertia tensor about the flange origin, flange axes, SI). W is the
payload's Newton–Euler regressor on the DH chain (``solvers.regressor.payload_regressor``): the flange's
angular velocity/acceleration and the linear acceleration of its origin (minus gravity)
give the wrench the flange exerts on the payload, and joint j carries its component
about the joint axis. In the static limit it reduces to ``Kinematics.payload_regressor``.

Velocity and acceleration are not taken from the controller: they come from the recorded
joint angles by Savitzky–Golay differentiation, as they would on a real robot.

Friction does not cancel fully in the difference (load-dependent friction, friction that
drifted between the runs). By default each moving joint gets two nuisance columns,
sign(q̇) and q̇ (a change of its Coulomb and viscous coefficients between the runs), and
samples of a moving joint near zero speed are left out of that joint's rows.

This solver is not in ``SOLVERS``: it needs its own trajectory, not the point-to-point
sweeps the rest of the pipeline records. The simulator's excitation run is
``benchmarks.excitation``; the accuracy benchmark compares it with the PTP methods.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers.regressor import payload_regressor
from payload_agent.solvers.results import Estimate
from payload_agent.solvers.wls import Group, cog_with_covariance, fit

NAME = "dynamic"
PARAMS = ("m", "m*cx", "m*cy", "m*cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
SG_WINDOW_S = 0.2  # Savitzky–Golay window: the excitation's highest harmonic is ≲ 1 Hz
SG_ORDER = 5
MOVING_RANGE_RAD = 1e-3  # a joint whose angle spans less than this is held still
MIN_SPEED_RAD_S = 0.02  # moving-joint samples slower than this are dropped (stick-slip, sign(q̇) unsure)


@dataclass
class ExcitationRecord:
    """One run along the excitation trajectory: what the controller streamed."""

    t: np.ndarray  # (n,) s since the trajectory started (both runs on the same time base)
    q: np.ndarray  # (n, 6) rad
    effort_nm: np.ndarray  # (n, 6) N·m at nominal gains
    source: str = "excitation"


def derivatives(t: np.ndarray, q: np.ndarray, window_s: float = SG_WINDOW_S,
                order: int = SG_ORDER) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed q, q̇, q̈ from sampled angles (Savitzky–Golay; needs a uniform sample period)."""
    from scipy.signal import savgol_filter

    t = np.asarray(t, float)
    dt = np.diff(t)
    h = float(np.median(dt))
    if not h > 0 or np.max(np.abs(dt - h)) > 0.05 * h:
        raise DataError("dynamic: the excitation samples are not evenly spaced in time; resample first")
    win = max(order + 2, int(round(window_s / h)) | 1)
    if len(t) <= win:
        raise DataError(f"dynamic: only {len(t)} samples, fewer than the {win}-sample derivative window")
    kw = dict(window_length=win, polyorder=order, axis=0, mode="interp")
    return (savgol_filter(q, deriv=0, **kw), savgol_filter(q, deriv=1, delta=h, **kw),
            savgol_filter(q, deriv=2, delta=h, **kw))


def _align(loaded: ExcitationRecord, empty: ExcitationRecord) -> tuple[np.ndarray, np.ndarray]:
    """Loaded samples inside the empty run's time span, and empty effort interpolated at their times."""
    inside = (loaded.t >= empty.t[0]) & (loaded.t <= empty.t[-1])
    if inside.sum() < 50:
        raise DataError("dynamic: the loaded and empty excitation runs hardly overlap in time")
    te = loaded.t[inside]
    e = np.column_stack([np.interp(te, empty.t, empty.effort_nm[:, c]) for c in range(empty.effort_nm.shape[1])])
    q_gap = np.max(np.abs(loaded.q[inside] - np.column_stack(
        [np.interp(te, empty.t, empty.q[:, c]) for c in range(empty.q.shape[1])])))
    if q_gap > 0.01:
        raise DataError(f"dynamic: the two runs did not follow the same trajectory (angles differ by "
                        f"{np.degrees(q_gap):.2f}°)")
    return inside, e


def joint_groups(W: np.ndarray, qd: np.ndarray, dtau_nm: np.ndarray, joints: Sequence[int], moving: Sequence[int],
                 label: str, min_rows: int = 1) -> list[Group]:
    """The fit's rows, one group per joint (``label``/j<n>): its ten regressor columns and, for a joint in
    ``moving``, a Coulomb and a viscous friction change column of its own; a moving joint's samples slower than
    ``MIN_SPEED_RAD_S`` (sign(q̇) unsure) are left out of its rows. A joint the payload does not load, or with
    fewer than ``min_rows`` rows, gets none."""
    moving = list(moving)
    n, n_par = len(qd), 10 + 2 * len(moving)
    groups = []
    for j in joints:
        Y = np.zeros((n, n_par))
        Y[:, :10] = W[:, j]
        keep = np.ones(n, bool)
        if j in moving:
            c = 10 + 2 * moving.index(j)
            Y[:, c], Y[:, c + 1] = np.sign(qd[:, j]), qd[:, j]
            keep = np.abs(qd[:, j]) >= MIN_SPEED_RAD_S
        if keep.sum() < max(min_rows, 1) or np.max(np.abs(Y[keep, :10])) < 1e-9:
            continue
        # one "sweep" per joint: the rows kept differ between joints (slow samples dropped)
        groups.append(Group(f"{label}/j{j + 1}", f"{label}/j{j + 1}", Y[keep], dtau_nm[keep, j], joint=j))
    return groups


def solve(loaded: ExcitationRecord, empty: ExcitationRecord, kin: Kinematics, *,
          joints: Sequence[int] | None = None, friction: bool = True, sg_window_s: float = SG_WINDOW_S,
          sg_order: int = SG_ORDER) -> Estimate:
    """Mass and centre of mass (and inertia, in the notes) from loaded − empty along one trajectory.

    ``joints`` (0-based) whose torques enter the fit: default all six. ``friction`` adds the
    per-moving-joint Coulomb/viscous change columns. Weighted LS with ``payload_agent.solvers.wls.fit``
    (one pass, then weights 1/σ² per joint, autocorrelation-robust covariance per joint);
    the covariance is of all parameters, and the mass / centre-of-mass uncertainty is its
    marginal.
    """
    joints = tuple(range(loaded.q.shape[1])) if joints is None else tuple(joints)
    inside, e_empty = _align(loaded, empty)
    q, qd, qdd = derivatives(loaded.t, loaded.q, sg_window_s, sg_order)
    q, qd, qdd = q[inside], qd[inside], qdd[inside]
    dtau = loaded.effort_nm[inside] - e_empty
    moving = [j for j in joints if np.ptp(loaded.q[:, j]) > MOVING_RANGE_RAD] if friction else []
    groups = joint_groups(payload_regressor(kin, q, qd, qdd), qd, dtau, joints, moving, "excitation")
    res = fit(groups)
    theta, cov = res.theta, res.cov
    mass = float(theta[0])
    if not mass > 0:
        raise DataError(f"dynamic: identified mass {mass:.4f} kg is not positive; is a payload mounted?")
    c, cov_c = cog_with_covariance(theta[:4], cov[:4, :4])
    inertia = ", ".join(f"{name}={v:.4g}" for name, v in zip(PARAMS[4:], theta[4:10]))
    notes = [f"inertia about the flange origin (kg·m², flange axes): {inertia}"]
    if moving:
        notes.append("friction change columns for joints " + ", ".join(str(j + 1) for j in moving))
    return Estimate(
        solver=NAME,
        mass_kg=mass,
        cog_m=(float(c[0]), float(c[1]), float(c[2])),
        residual_rms_nm=res.residual_rms_nm,
        samples={g.label: len(g.y) for g in groups},
        mass_std_kg=float(np.sqrt(max(cov[0, 0], 0.0))),
        cog_std_m=tuple(float(np.sqrt(max(v, 0.0))) for v in np.diag(cov_c)),
        covariance=cov[:4, :4],
        condition_number=res.condition_number,
        notes=notes,
    )
