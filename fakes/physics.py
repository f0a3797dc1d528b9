"""Rigid-body physics of a simulated arm: a MuJoCo model built from DH data, plus friction.

The simulator's truth lives here: the arm's links, the payload on its flange and the
friction of each joint. Protocol front ends never touch MuJoCo directly; they read
``SimRobot`` states (see ``sim_robot``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from payload_agent.model.kinematics import DHRow, GRAVITY_M_S2, fixed_part


@dataclass(frozen=True)
class LinkInertia:
    """Inertial data of one link, expressed in its DH frame i (at the link's distal joint)."""

    mass_kg: float
    com_m: tuple[float, float, float]
    inertia_kgm2: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    # (ixx, iyy, izz, ixy, ixz, iyz) about the COM, axes of DH frame i


@dataclass(frozen=True)
class ArmSpec:
    """Everything the simulator needs to know about one robot model."""

    name: str
    dh: tuple[DHRow, ...]
    links: tuple[LinkInertia, ...]
    max_speed_rad_s: tuple[float, ...]
    max_accel_rad_s2: tuple[float, ...]
    armature_kgm2: tuple[float, ...] = (0.0,) * 6  # reflected rotor inertia per joint
    rated_torque_nm: tuple[float, ...] = (1.0,) * 6

    def with_dh_errors(self, rng: np.random.Generator, max_error_m: float) -> "ArmSpec":
        """A copy whose link lengths and offsets are off by up to ``max_error_m`` (uniform)."""
        rows = []
        for row in self.dh:
            da = rng.uniform(-max_error_m, max_error_m) if abs(row.a_m) > 0 else 0.0
            dd = rng.uniform(-max_error_m, max_error_m) if abs(row.d_m) > 0 else 0.0
            rows.append(replace(row, a_m=row.a_m + da, d_m=row.d_m + dd))
        return replace(self, dh=tuple(rows))


@dataclass(frozen=True)
class PayloadTruth:
    """The tool on the flange: what payload-agent has to find."""

    mass_kg: float
    cog_m: tuple[float, float, float]  # flange frame
    inertia_kgm2: tuple[float, float, float] = (0.0, 0.0, 0.0)  # principal moments, about the COM
    axes_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # principal axes in flange axes (w, x, y, z)

    @classmethod
    def from_tensor(cls, mass_kg: float, cog_m: Sequence[float], inertia_com_kgm2) -> "PayloadTruth":
        """A tool with a full inertia tensor about its centre of mass (3×3, flange axes)."""
        from scipy.spatial.transform import Rotation

        tensor = np.asarray(inertia_com_kgm2, float)
        moments, vectors = np.linalg.eigh(0.5 * (tensor + tensor.T))
        if np.linalg.det(vectors) < 0:
            vectors[:, 2] *= -1
        x, y, z, w = Rotation.from_matrix(vectors).as_quat()
        return cls(float(mass_kg), tuple(float(c) for c in cog_m), tuple(float(v) for v in moments),
                   (float(w), float(x), float(y), float(z)))

    @property
    def inertia_com_kgm2(self) -> np.ndarray:
        """The 3×3 tensor about the centre of mass in flange axes."""
        from scipy.spatial.transform import Rotation

        w, x, y, z = self.axes_quat
        R = Rotation.from_quat([x, y, z, w]).as_matrix()
        return R @ np.diag(self.inertia_kgm2) @ R.T

    @classmethod
    def point(cls, mass_kg: float, cog_mm: Sequence[float]) -> "PayloadTruth":
        x, y, z = (float(v) / 1000.0 for v in cog_mm)
        # a solid cube of 6 cm edge: small but non-zero rotational inertia
        i = mass_kg * (0.06**2) / 6.0
        return cls(float(mass_kg), (x, y, z), (i, i, i))


@dataclass
class FrictionParams:
    """Joint friction: Coulomb + viscous + a Coulomb part proportional to the load torque.

    τ_f = scale · factor · [d·(1 + a·d)·coulomb + d·load_ratio·|τ_load| + viscous · q̇],  d = tanh(q̇/ε)

    ``asymmetry`` a: the constant Coulomb level is (1 + a)·coulomb moving positive and (1 − a)·coulomb
    moving negative (Fc+ ≠ Fc−; 0: symmetric; d·(1 + a·d) vanishes at rest); the load-dependent part
    stays symmetric. ``factor``: a per-joint multiplier the caller passes, e.g. the temperature
    dependence (``PhysicsEffects.friction_factor``).
    """

    coulomb_nm: np.ndarray = field(default_factory=lambda: np.zeros(6))
    viscous_nm_s_rad: np.ndarray = field(default_factory=lambda: np.zeros(6))
    load_ratio: np.ndarray = field(default_factory=lambda: np.zeros(6))
    smoothing_rad_s: float = 1e-3
    scale: float = 1.0
    asymmetry: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        self.coulomb_nm = np.broadcast_to(np.asarray(self.coulomb_nm, float), (6,)).copy()
        self.viscous_nm_s_rad = np.broadcast_to(np.asarray(self.viscous_nm_s_rad, float), (6,)).copy()
        self.load_ratio = np.broadcast_to(np.asarray(self.load_ratio, float), (6,)).copy()
        self.asymmetry = np.broadcast_to(np.asarray(self.asymmetry, float), (6,)).copy()

    def torque(self, qd: np.ndarray, tau_rigid: np.ndarray, factor: np.ndarray | float = 1.0) -> np.ndarray:
        # every simulated tick asks: a symmetric Coulomb level (d·(1 + 0·d) is d) and an overall gain of 1 skip
        # their products, which leave every value as it is
        direction = np.tanh(qd / self.smoothing_rad_s)
        level = direction if not self.asymmetry.any() else direction * (1.0 + self.asymmetry * direction)
        coulomb = level * self.coulomb_nm + direction * self.load_ratio * np.abs(tau_rigid)
        total = coulomb + self.viscous_nm_s_rad * qd
        if self.scale == 1.0 and isinstance(factor, float) and factor == 1.0:
            return total
        return self.scale * np.asarray(factor) * total


def _mujoco():
    """MuJoCo, imported for inverse dynamics only: the simulated arms never render, and without an OpenGL context
    its import skips GLFW (0.5 s instead of 0.65-1.0 s per simulated controller's process; a value set is kept)."""
    os.environ.setdefault("MUJOCO_GL", "disable")
    import mujoco

    return mujoco


def _mat_to_quat(R: np.ndarray) -> np.ndarray:
    mujoco = _mujoco()
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).flatten())
    return quat


def _fmt(values) -> str:
    return " ".join(f"{float(v):.17g}" for v in values)


def build_mjcf(spec: ArmSpec) -> str:
    """MJCF text of the arm: body i turns about its z axis by the DH angle of joint i."""
    parts = [
        f'<mujoco model="{spec.name}">',
        '<compiler angle="radian" inertiafromgeom="false" autolimits="true"/>',
        f'<option gravity="0 0 {-GRAVITY_M_S2!r}" timestep="0.002"/>',
        "<worldbody>",
    ]
    closers = []
    parent_fixed = np.eye(4)
    for i, (row, link) in enumerate(zip(spec.dh, spec.links)):
        pos = parent_fixed[:3, 3]
        quat = _mat_to_quat(parent_fixed[:3, :3])
        F = fixed_part(row)  # body frame -> DH frame i
        com_body = F[:3, :3] @ np.asarray(link.com_m) + F[:3, 3]
        ixx, iyy, izz, ixy, ixz, iyz = link.inertia_kgm2
        I_dh = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        I_body = F[:3, :3] @ I_dh @ F[:3, :3].T
        if np.allclose(I_body, 0):
            I_body = np.eye(3) * 1e-6
        full = (I_body[0, 0], I_body[1, 1], I_body[2, 2], I_body[0, 1], I_body[0, 2], I_body[1, 2])
        parts.append(f'<body name="link{i + 1}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">')
        parts.append(f'<joint name="j{i + 1}" type="hinge" axis="0 0 1" armature="{spec.armature_kgm2[i]!r}"/>')
        parts.append(f'<inertial pos="{_fmt(com_body)}" mass="{max(link.mass_kg, 1e-6)!r}" fullinertia="{_fmt(full)}"/>')
        closers.append("</body>")
        parent_fixed = F
    # flange frame = DH frame n; the payload body hangs on it
    parts.append(f'<body name="flange" pos="{_fmt(parent_fixed[:3, 3])}" quat="{_fmt(_mat_to_quat(parent_fixed[:3, :3]))}">')
    parts.append('<body name="payload"><inertial pos="0 0 0" mass="1" diaginertia="1e-3 1e-3 1e-3"/></body>')
    parts.append("</body>")
    parts.extend(closers)
    parts.append("</worldbody></mujoco>")
    return "\n".join(parts)


class ArmPhysics:
    """Inverse dynamics of the arm and its current payload (not thread-safe; SimRobot locks)."""

    def __init__(self, spec: ArmSpec, payload: PayloadTruth | None = None):
        mujoco = self._mj = _mujoco()
        self.spec = spec
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(spec))
        self.data = mujoco.MjData(self.model)
        self._payload_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "payload")
        self._offsets = np.array([row.offset_rad for row in spec.dh])
        self.payload: PayloadTruth | None = None
        self.set_payload(payload)

    def set_payload(self, payload: PayloadTruth | None) -> None:
        pid = self._payload_id
        if payload is None or payload.mass_kg <= 0:
            self.model.body_mass[pid] = 0.0
            self.model.body_ipos[pid] = 0.0
            self.model.body_inertia[pid] = 0.0
            self.payload = None
        else:
            self.model.body_mass[pid] = payload.mass_kg
            self.model.body_ipos[pid] = payload.cog_m
            self.model.body_iquat[pid] = payload.axes_quat
            self.model.body_inertia[pid] = payload.inertia_kgm2
            self.payload = payload
        # MuJoCo caches derived constants (subtree masses, ...) at compile time: refresh them.
        self._mj.mj_setConst(self.model, self.data)

    def rigid_torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint torques (N·m) that move the rigid arm + payload along (q, q̇, q̈); q in controller angles."""
        d = self.data
        d.qpos[:] = q + self._offsets
        d.qvel[:] = qd
        d.qacc[:] = qdd
        self._mj.mj_inverse(self.model, d)
        return d.qfrc_inverse.copy()
