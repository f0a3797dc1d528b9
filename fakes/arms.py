"""ArmSpec factories for the robots the fakes simulate (numbers and sources in robot_data)."""

from __future__ import annotations

import math

from payload_agent.fakes.physics import ArmSpec, LinkInertia
from payload_agent.model.kinematics import DHRow

from payload_agent.fakes import robot_data as _data  # curated numbers with sources (docs/sources.md)


def _links(rows) -> tuple[LinkInertia, ...]:
    return tuple(LinkInertia(r["mass_kg"], tuple(r["com_m"]), tuple(r["inertia_kgm2"])) for r in rows)


def _dh(rows) -> tuple[DHRow, ...]:
    return tuple(DHRow(*row) for row in rows)


def ec66_spec() -> ArmSpec:
    """Elite Robots EC66 (6 kg payload)."""
    dh = _data.EC66_DH
    links = _data.EC66_LINKS
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


def ur5e_spec() -> ArmSpec:
    """Universal Robots UR5e (5 kg payload)."""
    dh = _data.UR5E_DH
    links = _data.UR5E_LINKS
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


def canopen_arm_spec() -> ArmSpec:
    """The simulated CANopen arm (fakes/canopen): UR3e geometry and masses on six CiA 402 drives."""
    return ArmSpec(
        name="canopen_arm",
        dh=_dh(_data.CANOPEN_ARM_DH),
        links=_links(_data.CANOPEN_ARM_LINKS),
        max_speed_rad_s=tuple(math.radians(v) for v in _data.CANOPEN_ARM_MAX_SPEED_DEG_S),
        max_accel_rad_s2=(8.0,) * 6,
        armature_kgm2=(0.05, 0.05, 0.03, 0.01, 0.01, 0.01),
        rated_torque_nm=tuple(float(v) for v in _data.CANOPEN_ARM_RATED_TORQUE_NM),
    )


SPECS["canopen_arm"] = canopen_arm_spec


# the stream of the simulation's seed the DH-length errors are drawn from (the other draws keep theirs)
DH_ERROR_STREAM = 22


def simulated_spec(sim) -> ArmSpec:
    """The arm a ``simulation`` section describes (``configuration.simulation.SimulationConfig``): its arm's spec, each
    non-zero DH length off by a uniform draw within ± ``dh_length_error_mm`` (``ArmSpec.with_dh_errors``, as the
    accuracy benchmark's arms), drawn from the simulation's seed; the exact spec when that is 0 (the shipped configs)."""
    spec = SPECS[sim.arm]()
    error_mm = float(getattr(sim, "dh_length_error_mm", 0.0))
    if error_mm <= 0:
        return spec
    import numpy as np

    rng = np.random.default_rng((int(sim.seed) % 2 ** 32, DH_ERROR_STREAM))
    return spec.with_dh_errors(rng, error_mm / 1000.0)
