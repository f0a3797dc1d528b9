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


def _dh_batch(theta: np.ndarray, a: float, d: float, alpha: float) -> np.ndarray:
    """Standard-DH transforms for an array of joint angles: (n, 4, 4)."""
    n = len(theta)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros((n, 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 0, 2], T[:, 0, 3] = ct, -st * ca, st * sa, a * ct
    T[:, 1, 0], T[:, 1, 1], T[:, 1, 2], T[:, 1, 3] = st, ct * ca, -ct * sa, a * st
    T[:, 2, 1], T[:, 2, 2], T[:, 2, 3] = sa, ca, d
    T[:, 3, 3] = 1.0
    return T


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
    """
    q = np.atleast_2d(np.asarray(q, float))
    frames = [np.broadcast_to(np.eye(4), (len(q), 4, 4))]
    for i, row in enumerate(kin.rows):
        frames.append(frames[-1] @ _dh_batch(q[:, i] + row.offset_rad, row.a_m, row.d_m, row.alpha_rad))
    return frames


def payload_regressor(kin: Kinematics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                      g: float = GRAVITY_M_S2) -> np.ndarray:
    """W with τ_payload[k, j] = W[k, j, :] · θ for every sample k and joint j: shape (n, 6, 10).

    Forward Newton–Euler recursion in the base frame (joint i turns about z of DH frame
    i−1 through its origin), then the payload's wrench at the flange origin:
        f = m·a' + ω̇ × (m c) + ω × (ω × (m c)),   a' = a_flange − g⃗_gravity
        n = I_O·ω̇ + ω × (I_O·ω) + (m c) × a'
    in flange axes, and τ_j = z_j · (R n + (p − o_j) × R f).
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
        w_new = w + qd[:, i:i + 1] * zi
        wd = wd + qdd[:, i:i + 1] * zi + np.cross(w, qd[:, i:i + 1] * zi)
        w = w_new
        r = o[:, i + 1] - o[:, i]
        acc = acc + np.cross(wd, r) + np.cross(w, np.cross(w, r))
    R = frames[-1][:, :3, :3]
    Rt = np.transpose(R, (0, 2, 1))
    w_f = np.einsum("nij,nj->ni", Rt, w)
    wd_f = np.einsum("nij,nj->ni", Rt, wd)
    a_f = np.einsum("nij,nj->ni", Rt, acc + np.array([0.0, 0.0, g]))
    Sw, Swd, Sa = _skew(w_f), _skew(wd_f), _skew(a_f)
    Yf = np.zeros((n_s, 3, 10))
    Yf[:, :, 0] = a_f
    Yf[:, :, 1:4] = Swd + Sw @ Sw
    Yn = np.zeros((n_s, 3, 10))
    Yn[:, :, 1:4] = -Sa
    Yn[:, :, 4:10] = _inertia_map(wd_f) + Sw @ _inertia_map(w_f)
    Yf_b = R @ Yf
    Yn_b = R @ Yn
    p = o[:, -1]
    W = np.zeros((n_s, n_j, 10))
    for j in range(n_j):
        lever = np.cross(z[:, j], p - o[:, j])  # z·(r × F) = (z × r)·F
        W[:, j] = np.einsum("ni,nik->nk", z[:, j], Yn_b) + np.einsum("ni,nik->nk", lever, Yf_b)
    return W


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
