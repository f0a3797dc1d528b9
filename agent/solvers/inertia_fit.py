"""The payload's inertia tensor from fast wrist moves, with mass and first moments from the static result.

Each wrist move is recorded twice, with the empty flange and with the tool. Per move the loaded
run goes onto an even time grid, the empty run is shifted onto it (the two trapezoids are matched
at the moment the moving joint passes the middle of its travel) and subtracted; what remains is
the payload's torque W(q, q̇, q̈)·θ plus a friction change. q̇ and q̈ come from the recorded angles
with one Gaussian kernel (``smoothed``): the torque difference is smoothed by the kernel
and q̈ is the kernel's second derivative applied to the angles, so both see the same filter
(convolution commutes with differentiation; a symmetric kernel has no delay) and the
trapezoid's acceleration steps are rounded alike on both sides. What the filter still does to
the nonlinear terms is a declared systematic term (``MODEL_REL_STD``) in the covariance.

m and m·c come from the static sweeps (hundreds of gravity-loaded samples in two orientations) and are
corrected by the wrist moves with the static result as their prior: the ten parameters are fitted
together and the four static ones combined with the sweeps' estimate and covariance (a Kalman update).
A static m·c error matters here because a gravity torque that changes with the moving joint's angle
correlates with the PTP move's q̈ = −a·sign(q − q_mid) and shows as inertia. The update is used only
when the wrist moves agree with the sweeps within their joint uncertainty (the normalised innovation
squared below ``NIS_LIMIT``, χ² with four degrees of freedom at 99.9 %); otherwise something in the wrist
moves that the model lacks (a tool cable or hose pulling on the wrist, a torque that depends on the wrist
angles) would drag m·c and the tensor with it, so m and m·c are held at the static result (their
covariance propagated) and the fit says why. Each moving wrist joint gets a Coulomb and a viscous
friction change column (its rows near zero speed, where sign(q̇) is unsure, are left out).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.recording.rundata import WristRecord
from payload_agent.solvers.dynamic import MIN_SPEED_RAD_S, MOVING_RANGE_RAD
from payload_agent.solvers.regressor import payload_regressor
from payload_agent.solvers.wls import Group, fit

# Noise-free simulated recordings (EC66, wrist_inertia, 2 kg tool) give the tensor within 8 % of its largest element:
# the kernel rounds the trapezoid's steps for the nonlinear (ω², q-dependent) terms too. Declared as a standard
# uncertainty on every element, added in quadrature to the fit's own, relative to the largest diagonal element of the
# tensor about the flange origin. (Measured again in session 10: noise-free with exact m·c the error is 0.4-3.2 % of
# the largest principal moment, far less; but the fit's own σ alone is about 20 % low on the fixed-orientation test
# case, rms(error/σ) 1.19 over 72 elements, and this term covers that. Rebased to 3 % of the tensor about the CoM it
# left the σ too small: docs/analysis.md.)
MODEL_REL_STD = 0.05
SMOOTH_S = 0.02  # s, the Gaussian kernel's σ: longer lets less angle noise into q̈, shorter keeps the ramps
MIN_ROWS = 20
NIS_LIMIT = 18.47  # χ²(4) at 99.9 %: wrist moves and sweeps disagree about m, m·c beyond their σ (chi2.ppf(0.999, 4))
_I_INDEX = ((4, 5, 6), (5, 7, 8), (6, 8, 9))  # θ index of each tensor element
_VEC = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


@dataclass(frozen=True)
class InertiaFit:
    theta: np.ndarray  # (10,) m, m·c (updated or held), inertia about the flange origin (Ixx, Ixy, Ixz, Iyy, Iyz, Izz)
    cov: np.ndarray  # (10, 10)
    moves: tuple[str, ...]
    residual_rms_nm: dict[str, float]
    condition_number: float  # of the six inertia columns (column-scaled normal matrix)
    systematic_std: np.ndarray  # (6,) the smoothing's and model's declared term on the flange-origin elements
    samples: int
    static_nis: float  # the wrist moves' m, m·c against the sweeps': normalised innovation squared (nan: not fitted)
    static_held: str | None = None  # why m and m·c were held at the static result (None: updated by the wrist moves)

    def inertia_com(self) -> tuple[np.ndarray, np.ndarray]:
        """The tensor about the centre of mass (flange axes) and the 6×6 covariance of its elements (xx, xy, xz,
        yy, yz, zz), by the delta method from θ's covariance."""
        def vec(th: np.ndarray) -> np.ndarray:
            m, mc = th[0], th[1:4]
            io = np.array([[th[i] for i in row] for row in _I_INDEX])
            c = mc / m
            t = io - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
            return np.array([t[i, j] for i, j in _VEC])

        base = vec(self.theta)
        J = np.zeros((6, 10))
        for k in range(10):
            step = 1e-6 * max(abs(self.theta[k]), 1e-3)
            th = self.theta.copy()
            th[k] += step
            J[:, k] = (vec(th) - base) / step
        out = np.zeros((3, 3))
        for v, (i, j) in zip(base, _VEC):
            out[i, j] = out[j, i] = v
        return out, J @ self.cov @ J.T


def _pair(loaded: WristRecord, empty: WristRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, Δeffort) on an even grid over the loaded move, the empty run matched at mid-travel."""
    def even(rec: WristRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = float(np.median(np.diff(rec.t)))
        grid = np.arange(rec.t[0], rec.t[-1] + 0.5 * h, h)
        return grid, *(np.column_stack([np.interp(grid, rec.t, x[:, c]) for c in range(6)]) for x in (rec.q, rec.effort_nm))

    def mid_time(t: np.ndarray, q: np.ndarray, j: int) -> float:
        s = (q[:, j] - q[0, j]) / (q[-1, j] - q[0, j])
        k = int(np.argmax(s >= 0.5))
        return float(np.interp(0.5, s[k - 1:k + 1], t[k - 1:k + 1])) if k > 0 else float(t[0])

    if len(loaded.t) < MIN_ROWS or len(empty.t) < MIN_ROWS:
        raise DataError(f"wrist move {loaded.name}: too few samples ({len(loaded.t)} loaded, {len(empty.t)} empty)")
    j = int(np.argmax(np.abs(loaded.q[-1] - loaded.q[0])))
    if abs(empty.q[-1, j] - empty.q[0, j]) < 0.5 * abs(loaded.q[-1, j] - loaded.q[0, j]):
        raise DataError(f"wrist move {loaded.name}: the empty and loaded runs did not make the same move")
    t, q, e_l = even(loaded)
    shift = mid_time(empty.t, empty.q, j) - mid_time(loaded.t, loaded.q, j)
    inside = (t + shift >= empty.t[0]) & (t + shift <= empty.t[-1])
    e_e = np.column_stack([np.interp(t[inside] + shift, empty.t, empty.effort_nm[:, c]) for c in range(6)])
    return t[inside], q[inside], e_l[inside] - e_e


def smoothed(t: np.ndarray, q: np.ndarray, tau: np.ndarray, width_s: float):
    """g∗q, g′∗q, g″∗q and g∗τ for one Gaussian kernel g of standard deviation ``width_s``.

    Convolution commutes with differentiation, so g″∗q = g∗q̈: the acceleration the regressor sees
    is exactly the torque's own smoothing wherever the torque is linear in q̈ (the inertial part),
    with no delay (symmetric kernel) and no rounding mismatch at the trapezoid's acceleration steps.
    """
    from scipy.ndimage import correlate1d

    h = float(np.median(np.diff(t)))
    if not h > 0 or np.max(np.abs(np.diff(t) - h)) > 0.05 * h:
        raise DataError("inertia: the wrist-move samples are not evenly spaced in time; resample first")
    s = width_s / h
    m = np.arange(-int(np.ceil(4 * s)), int(np.ceil(4 * s)) + 1, dtype=float)
    g0 = np.exp(-0.5 * (m / s) ** 2)
    g0 /= g0.sum()
    # the kernel's derivatives, normalised on the samples so that they are exact on lines and parabolas
    g1 = m * g0 / np.sum(m * m * g0)
    c = np.sum(m * m * g0)
    g2 = (m * m - c) * g0
    g2 *= 2.0 / np.sum(g2 * m * m)
    f = [correlate1d(q, w, axis=0, mode="nearest") / h ** k for k, w in enumerate((g0, g1, g2))]
    return f[0], f[1], f[2], correlate1d(tau, g0, axis=0, mode="nearest")


def _groups(pairs, kin: Kinematics, theta_static: np.ndarray, joints: Sequence[int], window_s: float,
            free_static: bool = False):
    """One group per (move, joint). Columns: six inertia parameters, a Coulomb and a viscous friction change per
    moving wrist joint, and with ``free_static`` the four static parameters' corrections (m, m·c) last."""
    moving_all = sorted({k for _, _, q, _ in pairs for k in range(6) if np.ptp(q[:, k]) > MOVING_RANGE_RAD})
    n_fric = 6 + 2 * len(moving_all)
    n_par = n_fric + (4 if free_static else 0)
    groups, static_cols = [], []
    for name, t, q, dtau in pairs:
        qs, qd, qdd, dtau_f = smoothed(t, q, dtau, window_s)
        edge = int(np.ceil(3 * window_s / float(np.median(np.diff(t)))))  # the kernel's reach past the ends
        qs, qd, qdd, dtau_f, q = (x[edge:len(x) - edge] for x in (qs, qd, qdd, dtau_f, q))
        W = payload_regressor(kin, qs, qd, qdd)
        moving = [k for k in range(6) if np.ptp(q[:, k]) > MOVING_RANGE_RAD]
        for j in joints:
            Y = np.zeros((len(q), n_par))
            Y[:, :6] = W[:, j, 4:10]
            if free_static:
                Y[:, n_fric:] = W[:, j, :4]
            keep = np.ones(len(q), bool)
            if j in moving and j in moving_all:
                c = 6 + 2 * moving_all.index(j)
                Y[:, c], Y[:, c + 1] = np.sign(qd[:, j]), qd[:, j]
                keep = np.abs(qd[:, j]) >= MIN_SPEED_RAD_S
            if keep.sum() < MIN_ROWS or np.max(np.abs(Y[keep, :6])) < 1e-12:
                continue
            y = dtau_f[keep, j] - W[keep, j, :4] @ theta_static
            groups.append(Group(f"{name}/j{j + 1}", f"{name}/j{j + 1}", Y[keep], y, joint=j))  # rows differ by joint
            static_cols.append(W[keep, j, :4])
    return groups, np.vstack(static_cols) if static_cols else np.zeros((0, 4))


def fit_inertia(loaded: Mapping[str, WristRecord], empty: Mapping[str, WristRecord], kin: Kinematics,
                theta_static: np.ndarray, cov_static: np.ndarray, *, joints: Sequence[int] = range(6),
                gain_rel_std: Sequence[float] | None = None, window_s: float = SMOOTH_S,
                update_static: bool = True) -> InertiaFit:
    """The six inertia parameters (flange origin) from every wrist move recorded in both phases.

    m and m·c: updated by the wrist moves with the static result as prior where the two agree (module
    docstring), else (or with ``update_static`` False) held at the static result."""
    names = [n for n in loaded if n in empty]
    if not names:
        raise DataError("inertia: no wrist move was recorded both with the empty flange and with the tool")
    pairs = [(n, *_pair(loaded[n], empty[n])) for n in names]
    theta_static = np.asarray(theta_static, float)
    cov_static = np.asarray(cov_static, float)
    gains = None if gain_rel_std is None else list(gain_rel_std)
    nis, held = float("nan"), "m and m·c held at the sweeps' result, as asked"
    if update_static:
        groups, _ = _groups(pairs, kin, theta_static, tuple(joints), window_s, free_static=True)
        if not groups:
            raise DataError("inertia: no joint's torque depends on the payload's inertia along the wrist moves")
        res = fit(groups, gains)
        x, P, nis = _prior_update(res.theta, res.cov, cov_static)
        held = None if nis <= NIS_LIMIT else (
            f"the wrist moves disagree with the sweeps about mass and first moments (normalised innovation {nis:.3g}, "
            f"limit {NIS_LIMIT:g}): one of them carries a torque the model lacks (a stiff cable or hose, gear ripple "
            "that differs between the runs, a tool that shifted) or the sweeps' σ is too small; m and m·c were held "
            "at the sweeps' result")
    if held is None:
        th6, cov6 = x[:6], P[:6, :6]
        theta = np.concatenate([theta_static + x[-4:], th6])
        cross, cov_s = P[:6, -4:], P[-4:, -4:]
    else:
        groups, Y4 = _groups(pairs, kin, theta_static, tuple(joints), window_s)
        if not groups:
            raise DataError("inertia: no joint's torque depends on the payload's inertia along the wrist moves")
        res = fit(groups, gains)
        Y = np.vstack([g.Y for g in groups])
        th6, cov6 = res.theta[:6], res.cov[:6, :6]
        # m and m·c held: their covariance enters through dθ_I/dθ_s = −(YᵀWY)⁻¹ YᵀW Y_s
        G = -(res.normal_inverse @ (Y * res.weights[:, None]).T @ Y4)[:6]
        theta = np.concatenate([theta_static, th6])
        cov6 = cov6 + G @ cov_static @ G.T
        cross, cov_s = G @ cov_static, cov_static
    # what the smoothing and the model leave: declared, relative to the largest diagonal element (MODEL_REL_STD)
    diag = np.abs(th6[[0, 3, 5]])
    sys_std = MODEL_REL_STD * float(np.max(diag)) * np.ones(6)
    cov = np.zeros((10, 10))
    cov[:4, :4] = cov_s
    cov[4:, :4] = cross
    cov[:4, 4:] = cross.T
    cov[4:, 4:] = cov6 + np.diag(sys_std ** 2)
    Y6 = np.vstack([g.Y[:, :6] for g in groups])
    normal = (Y6 * res.weights[:, None]).T @ Y6
    d = 1.0 / np.sqrt(np.diag(normal))
    return InertiaFit(theta, cov, tuple(names), res.residual_rms_nm, float(np.linalg.cond(normal * np.outer(d, d))),
                      sys_std, sum(len(g.y) for g in groups), nis, held)


def _prior_update(x: np.ndarray, P: np.ndarray, cov_prior: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The joint estimate ``x`` (covariance ``P``), whose last four entries are corrections to the static m, m·c,
    combined with the static result (corrections 0, covariance ``cov_prior``): a Kalman update. Also returns the
    normalised innovation squared dᵀS⁻¹d of the corrections d (χ² with four degrees of freedom when both agree)."""
    H = np.zeros((4, len(x)))
    H[:, -4:] = np.eye(4)
    d = H @ x
    S = H @ P @ H.T + cov_prior
    K = np.linalg.solve(S, H @ P).T  # P Hᵀ S⁻¹ (S and P symmetric)
    P_new = P - K @ H @ P
    return x - K @ d, 0.5 * (P_new + P_new.T), float(d @ np.linalg.solve(S, d))
