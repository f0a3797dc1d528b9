"""The flange pose from a controller's TCP pose and TCP offset, both as position + rotation vector."""

from __future__ import annotations

import math

import numpy as np


def rotvec_matrix(r: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis × angle, as UR reports rx, ry, rz): Rodrigues' formula."""
    r = np.asarray(r, float)
    theta = float(np.linalg.norm(r))
    if theta < 1e-12:
        return np.eye(3)
    k = r / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * K @ K


def flange_from_tcp(p_tcp, r_tcp, p_offset=None, r_offset=None) -> tuple[np.ndarray, np.ndarray]:
    """Flange position (m) and rotation matrix: T_flange = T_tcp · T_offset⁻¹ (no offset: the TCP itself)."""
    R = rotvec_matrix(r_tcp)
    p = np.asarray(p_tcp, float)
    if p_offset is not None:
        Ro = rotvec_matrix(r_offset)
        R = R @ Ro.T
        p = p - R @ np.asarray(p_offset, float)
    return p, R
