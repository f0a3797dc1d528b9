"""The ``simulation`` section of a sim-*.yaml: the truth and the imperfections of the simulated robot.

Only simulated runs have it; the agent starts the driver's simulated controller (see
``payload_agent.fakes.base``) with these values and is never told the payload truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from payload_agent.configuration.yamlcheck import Node

N_JOINTS = 6
# the arms the physics core simulates (payload_agent.fakes.arms.SPECS; a test keeps the two equal)
SIMULATED_ARMS = ("ec66", "ur5e", "canopen_arm")
ZEROS = (0.0,) * N_JOINTS


@dataclass(frozen=True)
class SimPayload:
    mass_kg: float
    cog_mm: tuple[float, float, float]
    # the 3×3 inertia about the centre of mass, flange axes (kg·m²); None: a compact 6 cm cube of that mass
    inertia_com_kgm2: tuple[tuple[float, float, float], ...] | None = None


@dataclass(frozen=True)
class SimEffects:
    """``simulation.effects``: the error sources of a real arm the payload model does not have.

    All optional; absent means the ideal arm. Read by ``payload_agent.fakes.effects.from_simulation``
    (units as in the YAML; the physics core's docstrings say what each one does).
    """

    zero_offset_deg: tuple[float, ...] = ZEROS
    stiffness_nm_per_rad: tuple[float, ...] = ZEROS  # 0 = rigid
    coulomb_asymmetry: tuple[float, ...] = ZEROS
    friction_per_c: float = 0.0
    tool_warmup_c: float = 0.0
    ripple_amplitude_nm: tuple[float, ...] = ZEROS
    ripple_load_ratio: tuple[float, ...] = ZEROS
    gear_ratio: tuple[float, ...] = (100.0,) * N_JOINTS
    effort_quantum_nm: tuple[float, ...] = ZEROS
    cable_stiffness_nm_per_rad: tuple[float, ...] = (0.0, 0.0, 0.0)  # joints 4-6
    cable_rest_deg: tuple[float, ...] | None = None  # None: where the tool is mounted
    cable_preload_nm: tuple[float, ...] = (0.0, 0.0, 0.0)


EFFECT_KEYS = ("zero_offset_deg", "stiffness_nm_per_rad", "coulomb_asymmetry", "temperature", "torque_ripple",
               "effort_quantum_nm", "tool_cable")


def parse_effects(node: Node | None) -> SimEffects:
    if node is None:
        return SimEffects()
    node.allow(EFFECT_KEYS)
    zero = node.per_joint("zero_offset_deg", N_JOINTS, 0.0, min=-5, max=5)
    stiff = node.per_joint("stiffness_nm_per_rad", N_JOINTS, 0.0, min=0, max=1e8)
    asym = node.per_joint("coulomb_asymmetry", N_JOINTS, 0.0, min=-0.9, max=0.9)
    quantum = node.per_joint("effort_quantum_nm", N_JOINTS, 0.0, min=0, max=50)
    temp = node.child("temperature", required=False, keys=("friction_per_c", "tool_warmup_c"))
    per_c = temp.number("friction_per_c", 0.0, min=-0.05, max=0.05) if temp else 0.0
    warm = temp.number("tool_warmup_c", 0.0, min=-50, max=50) if temp else 0.0
    if temp:
        temp.reject_unknown()
    rip = node.child("torque_ripple", required=False, keys=("amplitude_nm", "load_ratio", "gear_ratio"))
    amp = rip.per_joint("amplitude_nm", N_JOINTS, 0.0, min=0, max=20) if rip else ZEROS
    lr = rip.per_joint("load_ratio", N_JOINTS, 0.0, min=0, max=0.2) if rip else ZEROS
    ratio = rip.per_joint("gear_ratio", N_JOINTS, 100.0, gt=0, max=1000) if rip else (100.0,) * N_JOINTS
    if rip:
        rip.reject_unknown()
    cab = node.child("tool_cable", required=False, keys=("stiffness_nm_per_rad", "rest_deg", "preload_nm"))
    k_c = cab.per_joint("stiffness_nm_per_rad", 3, 0.0, min=0, max=100) if cab else (0.0, 0.0, 0.0)
    rest = cab.numbers("rest_deg", 3, None, min=-360, max=360) if cab and cab.has("rest_deg") else None
    pre = cab.per_joint("preload_nm", 3, 0.0, min=-50, max=50) if cab else (0.0, 0.0, 0.0)
    if cab:
        cab.reject_unknown()
    node.reject_unknown()
    return SimEffects(zero, stiff, asym, per_c, warm, amp, lr, ratio, quantum, k_c, rest, pre)


@dataclass(frozen=True)
class SimulationConfig:
    """Only in sim-*.yaml: the agent starts a simulated controller with this truth (fakes/)."""

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
    angle_noise_rad: tuple[float, ...] = ZEROS  # reported joint angles: Gaussian noise per joint
    time_jitter_s: float = 0.0  # reported sample timestamps: Gaussian jitter (standard deviation)
    effects: SimEffects = field(default_factory=SimEffects)
    # effort noise of a standing joint (None: noise_nm, the in-motion level, whether it moves or stands)
    noise_rest_nm: tuple[float, ...] | None = None
    # the simulated arm's DH lengths against the YAML's kinematics, which the agent uses: each non-zero a and d off
    # by a uniform draw within ± this, seeded by ``seed`` (``fakes.arms.simulated_spec``); 0: exact, as shipped
    dh_length_error_mm: float = 0.0
    # each commanded motion draws its noise from generators seeded by (seed, session, motion number), so a seeded
    # session repeats its motions' noise however late a loaded host delivers the commands (``SimRobot``); the
    # default. Off: one stream per tick, whose draws a motion gets depend on the tick its command arrived at
    noise_per_move: bool = True
    # not a YAML key: which session of this simulated robot the cell starts (``session.simulation``), so that a
    # calibration, a stored baseline and the run after them do not draw the same noise
    session: int = 0


def _inertia(payload: Node) -> tuple[tuple[float, float, float], ...]:
    """``simulation.payload.inertia_com_kgm2``: a symmetric 3×3 a rigid body can have."""
    import numpy as np

    raw = payload.raw("inertia_com_kgm2")
    try:
        tensor = np.array(raw, dtype=float)
    except (TypeError, ValueError):
        tensor = np.zeros(0)
    if tensor.shape != (3, 3) or not np.all(np.isfinite(tensor)):
        raise payload.error("inertia_com_kgm2", f"expected three rows of three numbers (kg·m², about the centre "
                                                f"of mass, flange axes), got {raw!r:.80}")
    if not np.allclose(tensor, tensor.T, atol=1e-9):
        raise payload.error("inertia_com_kgm2", "is not symmetric (Ixy must equal Iyx, and so on)")
    moments = np.linalg.eigvalsh(tensor)
    if moments[0] <= 0 or moments[2] > moments[0] + moments[1] + 1e-12:
        raise payload.error("inertia_com_kgm2", f"no rigid body has it: principal moments "
                                                f"{', '.join(f'{v:.4g}' for v in moments)} kg·m² (all must be "
                                                "positive, and none larger than the other two together)")
    return tuple(tuple(float(v) for v in row) for row in tensor)


def parse_simulation(node: Node) -> SimulationConfig:
    arm = node.string("arm", choices=SIMULATED_ARMS)
    p = node.child("payload")
    payload = SimPayload(p.number("mass_kg", min=0, max=50), p.numbers("cog_mm", 3, min=-1000, max=1000),
                         _inertia(p) if p.has("inertia_com_kgm2") else None)
    p.reject_unknown(["mass_kg", "cog_mm", "inertia_com_kgm2"])
    noise = node.per_joint("noise_nm", N_JOINTS, min=0, max=100)
    noise_rest = node.per_joint("noise_rest_nm", N_JOINTS, min=0, max=100) if node.has("noise_rest_nm") else None
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
    angle_noise = node.per_joint("angle_noise_rad", N_JOINTS, 0.0, min=0, max=0.01)
    jitter_ms = node.number("timestamp_jitter_ms", 0.0, min=0, max=100)
    effects = parse_effects(node.child("effects", required=False))
    dh_error_mm = node.number("dh_length_error_mm", 0.0, min=0, max=5)
    per_move = node.boolean("noise_per_move", True)
    node.reject_unknown(["arm", "payload", "noise_nm", "noise_rest_nm", "friction", "drive_gain_error", "time_scale",
                         "seed", "start_deg", "angle_noise_rad", "timestamp_jitter_ms", "effects", "dh_length_error_mm",
                         "noise_per_move"])
    return SimulationConfig(arm, payload, noise, coulomb, viscous, load, drift, gain_err, scale, seed, start,
                            angle_noise, jitter_ms / 1000.0, effects, noise_rest, dh_error_mm, per_move)
