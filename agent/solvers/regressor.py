"""The payload's regressor: joint torques linear in its inertial parameters, on the DH chain.

Shared by the general solver (static gravity plus the centripetal load of a joint turning at
constant speed: the first four columns of ``payload_regressor`` with q̈ = 0) and the dynamic
baseline (all ten columns along an excitation trajectory), so neither solver imports the other.

θ = [m, m·cx, m·cy, m·cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]: first moments and inertia tensor about
the flange origin, flange axes, SI. Sign convention as ``Kinematics.payload_regressor``
(support force m·g·ẑ).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from payload_agent.model.kinematics import GRAVITY_M_S2, Kinematics


def _skew(v: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3, 3) cross-product matrices."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def _inertia_map(w: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3, 6): I·w as a linear map of (Ixx, Ixy, Ixz, Iyy, Iyz, Izz)."""
    L = np.zeros((len(w), 3, 6))
    L[:, 0, 0], L[:, 0, 1], L[:, 0, 2] = w[:, 0], w[:, 1], w[:, 2]
    L[:, 1, 1], L[:, 1, 3], L[:, 1, 4] = w[:, 0], w[:, 1], w[:, 2]
    L[:, 2, 2], L[:, 2, 4], L[:, 2, 5] = w[:, 0], w[:, 1], w[:, 2]
    return L


def chain_frames(kin: Kinematics, q: np.ndarray) -> list[np.ndarray]:
    """Base-frame transforms of DH frames 0..6 for every sample: a list of seven (n, 4, 4) arrays.

    Joint i (0-based) turns about z of frame i through its origin; frame 6 is the flange.
    (``Kinematics.frames``: the forward kinematics live in one place.)
    """
    return kin.frames(q)


def payload_regressor(kin: Kinematics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                      g: float = GRAVITY_M_S2, inertia: bool = True) -> np.ndarray:
    """W with τ_payload[k, j] = W[k, j, :] · θ for every sample k and joint j: shape (n, 6, 10).

    Forward Newton–Euler recursion in the base frame (joint i turns about z of DH frame
    i−1 through its origin), then the payload's wrench at the flange origin:
        f = m·a' + ω̇ × (m c) + ω × (ω × (m c)),   a' = a_flange − g⃗_gravity
        n = I_O·ω̇ + ω × (I_O·ω) + (m c) × a'
    in flange axes, and τ_j = z_j · (R n + (p − o_j) × R f).

    ``inertia=False`` gives only the first four columns, (n, 6, 4) (the general solver's model and every
    fit of a PTP run): the same numbers without the inertia columns' cost.
    """
    q, qd, qdd = (np.atleast_2d(np.asarray(x, float)) for x in (q, qd, qdd))
    n_s, n_j = q.shape
    frames = chain_frames(kin, q)
    z = np.stack([f[:, :3, 2] for f in frames[:-1]], axis=1)  # (n, 6, 3) joint axes
    o = np.stack([f[:, :3, 3] for f in frames], axis=1)  # (n, 7, 3) frame origins
    w = np.zeros((n_s, 3))
    wd = np.zeros((n_s, 3))
    acc = np.zeros((n_s, 3))
    for i in range(n_j):
        zi = z[:, i]
        turning, speeding = bool(np.any(qd[:, i])), bool(np.any(qdd[:, i]))  # a still joint adds nothing to ω, ω̇
        if turning or speeding:
            w_i = qd[:, i:i + 1] * zi
            wd = wd + qdd[:, i:i + 1] * zi + _cross(w, w_i)
            w = w + w_i
        if turning or speeding or np.any(w) or np.any(wd):  # before the first moving joint the links stand still
            r = o[:, i + 1] - o[:, i]
            acc = acc + _cross(wd, r) + _cross(w, _cross(w, r))
    R = frames[-1][:, :3, :3]
    Rt = np.transpose(R, (0, 2, 1))
    w_f = np.einsum("nij,nj->ni", Rt, w)
    wd_f = np.einsum("nij,nj->ni", Rt, wd)
    a_f = np.einsum("nij,nj->ni", Rt, acc + np.array([0.0, 0.0, g]))
    Sw, Swd, Sa = _skew(w_f), _skew(wd_f), _skew(a_f)
    cols = 10 if inertia else 4
    Yf = np.zeros((n_s, 3, cols))
    Yf[:, :, 0] = a_f
    Yf[:, :, 1:4] = Swd + Sw @ Sw
    Yn = np.zeros((n_s, 3, cols))
    Yn[:, :, 1:4] = -Sa
    if inertia:
        Yn[:, :, 4:10] = _inertia_map(wd_f) + Sw @ _inertia_map(w_f)
    p = o[:, -1]
    levers = _cross(z.reshape(-1, 3), (p[:, None, :] - o[:, :n_j]).reshape(-1, 3)).reshape(n_s, n_j, 3)  # z × r
    # z·(R n) + (z × r)·(R f), every joint at once: (n, 6, 3) @ (n, 3, cols)
    return (z @ R) @ Yn + (levers @ R) @ Yf


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b for (n, 3) arrays, component-wise (np.cross's axis juggling costs more than the math)."""
    return np.stack((a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), axis=1)


def centripetal_regressors(kin: Kinematics, q: np.ndarray, joints: Iterable[int], moving: int,
                           speed_rad_s: float) -> np.ndarray:
    """``centripetal_regressor`` for every sample at once: q (N, 6) -> (N, len(joints), 4)."""
    joints = tuple(joints)
    q = np.atleast_2d(np.asarray(q, float))
    w2 = float(speed_rad_s) ** 2
    if w2 == 0.0:
        return np.zeros((len(q), len(joints), 4))
    frames = kin.frames(q)
    p, R = frames[-1][:, :3, 3], frames[-1][:, :3, :3]
    zk, ok = frames[moving][:, :3, 2], frames[moving][:, :3, 3]

    def A(v: np.ndarray) -> np.ndarray:  # (z_k z_kᵀ − I) v, row-wise
        return zk * np.einsum("ni,ni->n", zk, v)[:, None] - v

    f_m = A(p - ok)  # centripetal acceleration of the flange origin per ω²
    Y = np.empty((len(q), len(joints), 4))
    for r, j in enumerate(joints):
        z, a = frames[j][:, :3, 2], p - frames[j][:, :3, 3]
        Y[:, r, 0] = w2 * np.einsum("ni,ni->n", z, _cross(a, f_m))
        Y[:, r, 1:] = w2 * np.einsum("nij,ni->nj", R, A(_cross(z, a)) + _cross(f_m, z))  # Rᵀ(...)
    return Y


def centripetal_regressor(kin: Kinematics, q: np.ndarray, joints: Iterable[int], moving: int,
                          speed_rad_s: float) -> np.ndarray:
    """Rows added to Y(q) by carrying the payload round joint ``moving`` at constant speed ω.

    The payload's centre of mass x = p + R·c moves on a circle about the moving joint's axis
    (z_k through o_k) with acceleration ẍ = ω²·(z_k z_kᵀ − I)(x − o_k); the arm supplies the
    force m·ẍ, which loads joint j with z_j·((x − o_j) × m·ẍ). Expanded, this is linear in θ
    except for a term in m·c·cᵀ (a rotational-inertia effect, left out). Same sign convention
    as ``Kinematics.payload_regressor`` (support force m·g·ẑ). One sample of
    ``centripetal_regressors``.
    """
    return centripetal_regressors(kin, np.asarray(q, float)[None, :], joints, moving, speed_rad_s)[0]


def regressors(kin: Kinematics, q: np.ndarray, joints: Iterable[int], moving: int | None = None,
               speed_rad_s: float = 0.0) -> np.ndarray:
    """``regressor`` for every sample at once: q (N, 6) -> (N, len(joints), 4)."""
    joints = tuple(joints)
    Y = kin.payload_regressors(q, joints)
    if moving is not None and speed_rad_s:
        Y = Y + centripetal_regressors(kin, q, joints, moving, speed_rad_s)
    return Y


def regressor(kin: Kinematics, q: np.ndarray, joints: Iterable[int], moving: int | None = None,
              speed_rad_s: float = 0.0) -> np.ndarray:
    """Δτ_joints = regressor · θ at angles q, with joint ``moving`` turning at ``speed_rad_s`` (static: 0)."""
    joints = tuple(joints)
    Y = kin.payload_regressor(q, joints)
    if moving is not None and speed_rad_s:
        Y = Y + centripetal_regressor(kin, q, joints, moving, speed_rad_s)
    return Y
