"""ArmSpec factories for the robots the fakes simulate (numbers and sources in robot_data)."""

from __future__ import annotations

import math

from payload_agent.fakes.physics import ArmSpec, LinkInertia
from payload_agent.kinematics import DHRow

try:  # curated data with sources; see docs/sources.md
    from payload_agent.fakes import robot_data as _data
except ImportError:  # pragma: no cover - only while robot_data is being written
    _data = None


def _links(rows) -> tuple[LinkInertia, ...]:
    return tuple(LinkInertia(r["mass_kg"], tuple(r["com_m"]), tuple(r["inertia_kgm2"])) for r in rows)


def _dh(rows) -> tuple[DHRow, ...]:
    return tuple(DHRow(*row) for row in rows)


_PROVISIONAL_EC66_DH = [
    (0.0, 0.096, math.pi / 2, 0.0),
    (-0.418, 0.0, 0.0, 0.0),
    (-0.398, 0.0, 0.0, 0.0),
    (0.0, 0.122, math.pi / 2, 0.0),
    (0.0, 0.098, -math.pi / 2, 0.0),
    (0.0, 0.089, 0.0, 0.0),
]
_PROVISIONAL_EC66_LINKS = [
    {"mass_kg": 3.0, "com_m": (0.0, -0.02, 0.0), "inertia_kgm2": (0.01, 0.01, 0.008, 0, 0, 0)},
    {"mass_kg": 6.5, "com_m": (0.209, 0.0, 0.11), "inertia_kgm2": (0.02, 0.15, 0.15, 0, 0, 0)},
    {"mass_kg": 2.3, "com_m": (0.2, 0.0, 0.02), "inertia_kgm2": (0.005, 0.05, 0.05, 0, 0, 0)},
    {"mass_kg": 1.1, "com_m": (0.0, -0.002, 0.015), "inertia_kgm2": (0.002, 0.002, 0.0015, 0, 0, 0)},
    {"mass_kg": 1.1, "com_m": (0.0, 0.002, 0.015), "inertia_kgm2": (0.002, 0.002, 0.0015, 0, 0, 0)},
    {"mass_kg": 0.35, "com_m": (0.0, 0.0, -0.01), "inertia_kgm2": (0.0002, 0.0002, 0.0003, 0, 0, 0)},
]


def ec66_spec() -> ArmSpec:
    """Elite Robots EC66 (6 kg payload)."""
    dh = getattr(_data, "EC66_DH", _PROVISIONAL_EC66_DH)
    links = getattr(_data, "EC66_LINKS", _PROVISIONAL_EC66_LINKS)
    # moveByJoint's speed percentage refers to one joint speed, 144°/s on the EC66 (the paper's
    # 100 %); the fake uses it for every joint so percent means the same to agent and fake.
    speeds = [getattr(_data, "EC66_SPEED_100PCT_DEG_S", 144.0)] * 6
    rated = getattr(_data, "EC66_RATED_TORQUE_NM", [150.0, 150.0, 150.0, 28.0, 28.0, 28.0])
    return ArmSpec(
        name="ec66",
        dh=_dh(dh),
        links=_links(links),
        max_speed_rad_s=tuple(math.radians(v) for v in speeds),
        max_accel_rad_s2=(6.0,) * 6,
        armature_kgm2=(0.2, 0.2, 0.1, 0.03, 0.03, 0.03),
        rated_torque_nm=tuple(float(v) for v in rated),
    )


_PROVISIONAL_UR5E_DH = [
    (0.0, 0.1625, math.pi / 2, 0.0),
    (-0.425, 0.0, 0.0, 0.0),
    (-0.3922, 0.0, 0.0, 0.0),
    (0.0, 0.1333, math.pi / 2, 0.0),
    (0.0, 0.0997, -math.pi / 2, 0.0),
    (0.0, 0.0996, 0.0, 0.0),
]
_PROVISIONAL_UR5E_LINKS = [
    {"mass_kg": 3.761, "com_m": (0.0, -0.02561, 0.00193), "inertia_kgm2": (0.0067, 0.0064, 0.0067, 0, 0, 0)},
    {"mass_kg": 8.058, "com_m": (0.2125, 0.0, 0.11336), "inertia_kgm2": (0.0149, 0.1338, 0.1338, 0, 0, 0)},
    {"mass_kg": 2.846, "com_m": (0.15, 0.0, 0.0265), "inertia_kgm2": (0.0041, 0.0312, 0.0312, 0, 0, 0)},
    {"mass_kg": 1.37, "com_m": (0.0, -0.0018, 0.01634), "inertia_kgm2": (0.0013, 0.0013, 0.0012, 0, 0, 0)},
    {"mass_kg": 1.3, "com_m": (0.0, 0.0018, 0.01634), "inertia_kgm2": (0.0013, 0.0013, 0.0012, 0, 0, 0)},
    {"mass_kg": 0.365, "com_m": (0.0, 0.0, -0.001159), "inertia_kgm2": (0.0002, 0.0002, 0.0002, 0, 0, 0)},
]


def ur5e_spec() -> ArmSpec:
    """Universal Robots UR5e (5 kg payload)."""
    dh = getattr(_data, "UR5E_DH", _PROVISIONAL_UR5E_DH)
    links = getattr(_data, "UR5E_LINKS", _PROVISIONAL_UR5E_LINKS)
    speeds = getattr(_data, "UR5E_MAX_SPEED_DEG_S", [180.0] * 6)
    return ArmSpec(
        name="ur5e",
        dh=_dh(dh),
        links=_links(links),
        max_speed_rad_s=tuple(math.radians(v) for v in speeds),
        max_accel_rad_s2=(8.0,) * 6,
        armature_kgm2=(0.15, 0.15, 0.08, 0.02, 0.02, 0.02),
        rated_torque_nm=(150.0, 150.0, 150.0, 28.0, 28.0, 28.0),
    )


SPECS = {"ec66": ec66_spec, "ur5e": ur5e_spec}
