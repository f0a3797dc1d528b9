"""The ``simulation`` section of a sim-*.yaml: the truth and the imperfections of the simulated robot.

Only simulated runs have it; the agent starts the driver's simulated controller (see
``payload_agent.fakes.base``) with these values and is never told the payload truth.
"""

from __future__ import annotations

from dataclasses import dataclass

from payload_agent.configuration.yamlcheck import Node

N_JOINTS = 6


@dataclass(frozen=True)
class SimPayload:
    mass_kg: float
    cog_mm: tuple[float, float, float]


@dataclass(frozen=True)
class SimulationConfig:
    """Only in sim-*.yaml: the agent starts a fake controller in-process with this truth."""

    arm: str
    payload: SimPayload
    noise_nm: tuple[float, ...]
    coulomb_nm: tuple[float, ...]
    viscous_nm_s_rad: tuple[float, ...]
    load_ratio: tuple[float, ...]
    friction_drift: float  # friction scale change at the tool change (e.g. 0.1 = +10 %)
    drive_gain_error: tuple[float, ...]  # multiplicative, per joint (1.0 = exact)
    time_scale: float
    seed: int
    start_deg: tuple[float, ...]  # where the simulated robot stands when the controller starts


def parse_simulation(node: Node) -> SimulationConfig:
    arm = node.string("arm")  # a name in payload_agent.fakes.arms.SPECS, checked when the simulation starts
    p = node.child("payload")
    payload = SimPayload(p.number("mass_kg", min=0, max=50), p.numbers("cog_mm", 3, min=-1000, max=1000))
    p.reject_unknown(["mass_kg", "cog_mm"])
    noise = node.per_joint("noise_nm", N_JOINTS, min=0, max=100)
    fr = node.child("friction")
    coulomb = fr.per_joint("coulomb_nm", N_JOINTS, min=0, max=200)
    viscous = fr.per_joint("viscous_nm_s_rad", N_JOINTS, min=0, max=1000)
    load = fr.per_joint("load_ratio", N_JOINTS, 0.0, min=0, max=1)
    drift = fr.number("drift", 0.0, min=-0.9, max=2.0)
    fr.reject_unknown(["coulomb_nm", "viscous_nm_s_rad", "load_ratio", "drift"])
    gain_err = node.per_joint("drive_gain_error", N_JOINTS, 1.0, gt=0.5, max=1.5)
    scale = node.number("time_scale", gt=0, max=1000)
    seed = node.integer("seed", 0)
    start = node.numbers("start_deg", N_JOINTS, min=-360, max=360)
    node.reject_unknown(["arm", "payload", "noise_nm", "friction", "drive_gain_error", "time_scale", "seed",
                         "start_deg"])
    return SimulationConfig(arm, payload, noise, coulomb, viscous, load, drift, gain_err, scale, seed, start)
