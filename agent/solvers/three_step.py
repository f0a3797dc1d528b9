"""The paper's three-step solver (Gao, Zhao, Li 2025, eqs. 23-25), lever geometry from FK.

1. mass from pose b: Δτ2(θ) − Δτ3(θ) = m·φ(θ), with Δτ2 from the joint-2 sweep and
   Δτ3 from the joint-3 sweep at the same link elevation θ (eq. 23); φ is the lever
   between the joint-2 and joint-3 axes, g·a2·cos θ for an ideal arm, taken from FK here;
2. x and y from joint 3 in pose b (eq. 24);
3. z from joint 3 in pose d with m, x (and y) known (eq. 25).
In each step the paper's cos θ/sin θ coefficients, and its a3+d5 and a3+d6 lever terms,
are the exact gravity-lever terms of the regressor Y(q) evaluated on the DH model, so the
signs and offsets follow whatever conventions the robot uses.
"""

from __future__ import annotations

import numpy as np

from payload_agent.model.arm_geometry import ArmGeometry
from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.model.kinematics import GRAVITY_M_S2, Kinematics
from payload_agent.types import SweepKey
from payload_agent.solvers.results import Estimate

NAME = "three-step"


def _find(deltas: dict[SweepKey, DeltaSweep], pose: str, joint: int) -> DeltaSweep:
    for key, d in deltas.items():
        if key.pose == pose and key.joint == joint and key.direction == "up":
            return d
    raise DataError(f"three-step needs the upward joint-{joint} sweep in pose {pose}, which the run does not have")


def _lever_terms(kin: Kinematics, q: np.ndarray, joint_index: int) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) per sample with Δτ_j = m·A + m·B·c: A from the flange position, B from its rotation."""
    rows = np.array([kin.payload_regressor(qi, [joint_index])[0] for qi in q])
    return rows[:, 0], rows[:, 1:]


def _axis_lever(kin: Kinematics, q: np.ndarray) -> np.ndarray:
    """φ = z2·((o3 − o2) × g⃗): the weight's lever between the joint-2 and joint-3 axes (g·a2·cos θ)."""
    g = np.array([0.0, 0.0, GRAVITY_M_S2])
    out = []
    for qi in q:
        pose = kin.pose(qi)
        out.append(pose.axis(1) @ np.cross(pose.origin(2) - pose.origin(1), g))
    return np.array(out)


def solve(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, *, pose_xy: str = "b", pose_z: str = "d") -> Estimate:
    b2, b3, d3 = _find(deltas, pose_xy, 2), _find(deltas, pose_xy, 3), _find(deltas, pose_z, 3)
    geo = ArmGeometry(kin, float(np.median(b2.q[:, 0])))

    # step 1 (eq. 23): pair joint-2 samples with the joint-3 sweep at the same link elevation
    elev_b2 = np.array([geo.elevations(q[1], q[2])[1] for q in b2.q])
    elev_b3 = np.array([geo.elevations(q[1], q[2])[1] for q in b3.q])
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
    A, B = _lever_terms(kin, b3.q, 2)
    rhs = b3.dtau[:, 2] / mass - A
    xy, *_ = np.linalg.lstsq(B[:, :2], rhs - 0.0, rcond=None)
    res2 = mass * (B[:, :2] @ xy - rhs)

    # step 3 (eq. 25): z cos θ = Δτ3/(m g) − (a3 + d6) cos θ − (x + l_s) sin θ, from joint 3 in pose d
    A, B = _lever_terms(kin, d3.q, 2)
    rhs = d3.dtau[:, 2] / mass - A - B[:, :2] @ xy
    z = float(B[:, 2] @ rhs / (B[:, 2] @ B[:, 2]))
    res3 = mass * (B[:, 2] * z - rhs)

    def rms(r):
        return float(np.sqrt(np.mean(r ** 2)))

    return Estimate(
        solver=NAME,
        mass_kg=mass,
        cog_m=(float(xy[0]), float(xy[1]), z),
        residual_rms_nm={f"{pose_xy}-j2/j3 (mass)": rms(res1), f"{b3.key.name} (x, y)": rms(res2),
                         f"{d3.key.name} (z)": rms(res3)},
        samples={b2.key.name: int(inside.sum()), b3.key.name: len(b3.q), d3.key.name: len(d3.q)},
    )
