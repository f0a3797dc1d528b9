"""The whole payload in the forms each controller takes (mass, centre of mass, inertia).

One identified payload, four ways to write it (docs/sources.md, "Payload forms"):

- **tensor**: the 3×3 inertia about the centre of mass, flange axes (what the agent identifies);
- **UR** ``set_target_payload(m, cog, inertia)`` / ur-rtde ``setTargetPayload``: CoG in m from
  the tool mount, inertia ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` in kg·m² about the CoG with axes
  parallel to the flange (tensor elements);
- **principal** (KUKA load data, OPC 40010 ``LoadType``): X, Y, Z of the CoG in mm, A, B, C in
  degrees the orientation of the principal axes relative to the flange (intrinsic z-y′-x″, as
  OPC 10000-210's RpyOrientationType and KUKA's ABC), JX, JY, JZ the principal moments;
- **Franka** ``setLoad`` / ``SetLoad``: mass, CoG in m, the 3×3 about the CoG column-major.

The principal axes of a tensor are defined up to order and sign; the orientation given is the
proper rotation with the smallest angle, so a tensor already diagonal in flange axes gives
A = B = C = 0 whatever the order of its moments.
"""

from __future__ import annotations

from itertools import permutations, product
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(moments (3,), rotation R (3, 3)) with inertia = R · diag(moments) · Rᵀ, R proper and closest to identity."""
    sym = 0.5 * (np.asarray(inertia, float) + np.asarray(inertia, float).T)
    moments, vectors = np.linalg.eigh(sym)
    best = None
    for order in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            R = vectors[:, order] * np.array(signs)
            if np.linalg.det(R) < 0:
                continue
            angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
            if best is None or angle < best[0] - 1e-12:
                best = (angle, moments[list(order)], R)
    return best[1], best[2]


def payload_forms(mass_kg: float, cog_m: Sequence[float], inertia_com: np.ndarray | None) -> dict[str, Any]:
    """Every controller's form of one payload; without inertia, the mass and CoG forms only."""
    cog = [float(v) for v in cog_m]
    forms: dict[str, Any] = {
        "ur": {"mass_kg": mass_kg, "cog_m": cog},
        "principal": {"mass_kg": mass_kg, "xyz_mm": [1000 * v for v in cog]},
        "franka": {"mass_kg": mass_kg, "cog_m": cog},
    }
    if inertia_com is None:
        return forms
    inertia = 0.5 * (np.asarray(inertia_com, float) + np.asarray(inertia_com, float).T)
    forms["tensor_com_kgm2"] = inertia.tolist()
    forms["ur"]["inertia_kgm2"] = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2],
                                   inertia[1, 2]]
    moments, R = principal_axes(inertia)
    a, b, c = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)
    forms["principal"].update({"abc_deg": [float(a), float(b), float(c)], "j_kgm2": moments.tolist()})
    forms["franka"]["inertia_column_major_kgm2"] = inertia.T.ravel().tolist()
    return forms
