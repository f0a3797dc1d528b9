"""The imperfections of a real arm that the payload model does not have: options of the physics core.

Every simulated controller serves one ``SimRobot``; these effects live there, so every protocol
front end serves them without knowing. Each one is off by default (``PhysicsEffects()`` is the
ideal arm); ``docs/sources.md`` ("Physics core: error sources") gives the realistic magnitudes
and where they come from. In order of the signal path:

- ``zero_offset_rad``: the joint's true zero differs from the controller's (encoder zeroing):
  link angle = controller angle − offset.
- ``stiffness_nm_per_rad``: gear elasticity. The controller follows its path with the motor-side
  encoder; the link lags by τ/k (τ = the torque through the gear). 0 = rigid.
- ``tool_cable``: a spring torque on the wrist joints that exists only while a tool is mounted
  (a cable or hose from the forearm to the tool). The payload model cannot represent it.
- ``coulomb_asymmetry``: Coulomb friction differs by direction: ×(1 + a) moving positive,
  ×(1 − a) moving negative (see ``FrictionParams``).
- ``friction_per_c`` / ``tool_warmup_c``: friction changes with joint temperature; the joints are
  ``tool_warmup_c`` warmer while a tool is mounted (a baseline recorded cold, a tool run warm).
- ``ripple``: position-dependent torque (gear mesh, cogging) with a load-dependent part, on the
  motor side: it shows in the effort, not in the link's motion.
- ``effort_quantum_nm``: the reported effort's resolution, for protocols that send floats but
  whose controller resolves no finer (front ends that encode integers quantise anyway).
- ``angle_noise_rad`` / ``time_jitter_s``: noise on the reported joint angles and on the
  controller timestamp of each sample. The simulated clock itself stays exact.
"""

from __future__ import annotations

from functools import cached_property
from dataclasses import dataclass, field
import numpy as np

N_JOINTS = 6
WRIST = slice(3, 6)  # joints 4–6 (0-based 3..5)


def _six(value, name: str) -> tuple[float, ...]:
    arr = np.broadcast_to(np.asarray(value, float), (N_JOINTS,))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: every value must be finite")
    return tuple(float(v) for v in arr)


def _three(value, name: str) -> tuple[float, float, float]:
    arr = np.broadcast_to(np.asarray(value, float), (3,))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: every value must be finite")
    return tuple(float(v) for v in arr)  # type: ignore[return-value]


@dataclass(frozen=True)
class TorqueRipple:
    """Position-dependent motor-side torque: Σ_h w_h · (A + L·|τ_gear|) · sin(n_h·q + φ_h).

    The default harmonics: the strain-wave gear mesh, twice per wave-generator turn (n = 2 × gear
    ratio cycles per output turn), and a slow once-per-output-turn part (circular-spline and
    bearing eccentricity) at 10 % of the mesh amplitude. Phases are drawn per joint from the robot's
    seed (``SimRobot``), so the empty and the loaded run of one robot see the same ripple.
    """

    amplitude_nm: tuple[float, ...] = (0.0,) * N_JOINTS
    load_ratio: tuple[float, ...] = (0.0,) * N_JOINTS  # extra amplitude per N·m of |gear torque|
    gear_ratio: tuple[float, ...] = (100.0,) * N_JOINTS
    once_per_rev_fraction: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude_nm", _six(self.amplitude_nm, "ripple.amplitude_nm"))
        object.__setattr__(self, "load_ratio", _six(self.load_ratio, "ripple.load_ratio"))
        object.__setattr__(self, "gear_ratio", _six(self.gear_ratio, "ripple.gear_ratio"))

    @cached_property  # asked every tick
    def active(self) -> bool:
        return any(self.amplitude_nm) or any(self.load_ratio)

    def torque(self, q: np.ndarray, tau_gear: np.ndarray, phases: np.ndarray) -> np.ndarray:
        """Ripple torque (N·m) at controller angles ``q``; ``phases`` (6, 2) radians."""
        amp = np.asarray(self.amplitude_nm) + np.asarray(self.load_ratio) * np.abs(tau_gear)
        mesh = np.sin(2.0 * np.asarray(self.gear_ratio) * q + phases[:, 0])
        slow = self.once_per_rev_fraction * np.sin(q + phases[:, 1])
        return amp * (mesh + slow)


@dataclass(frozen=True)
class ToolCable:
    """A cable or hose from the forearm to the tool: a spring on joints 4–6, only with a tool mounted.

    τ_j = k_j · (q_j − rest_j) + preload_j for the wrist joints (the torque the drives must add).
    ``rest_rad`` None: the wrist angles at the moment the tool is mounted (the cable was fitted
    there, relaxed). Both ends sit distal to joint 3, so joints 1–3 feel none of it.
    """

    stiffness_nm_per_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rest_rad: tuple[float, float, float] | None = None
    preload_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "stiffness_nm_per_rad", _three(self.stiffness_nm_per_rad, "cable stiffness"))
        object.__setattr__(self, "preload_nm", _three(self.preload_nm, "cable preload"))
        if self.rest_rad is not None:
            object.__setattr__(self, "rest_rad", _three(self.rest_rad, "cable rest angles"))

    @cached_property  # asked every tick
    def active(self) -> bool:
        return any(self.stiffness_nm_per_rad) or any(self.preload_nm)

    def torque(self, q_link: np.ndarray, rest: np.ndarray) -> np.ndarray:
        out = np.zeros(N_JOINTS)
        out[WRIST] = (np.asarray(self.stiffness_nm_per_rad) * (np.asarray(q_link)[WRIST] - rest)
                      + np.asarray(self.preload_nm))
        return out


@dataclass(frozen=True)
class PhysicsEffects:
    """Every error source of the physics core; the defaults are an ideal arm."""

    angle_noise_rad: tuple[float, ...] = (0.0,) * N_JOINTS
    time_jitter_s: float = 0.0
    zero_offset_rad: tuple[float, ...] = (0.0,) * N_JOINTS
    stiffness_nm_per_rad: tuple[float, ...] = (0.0,) * N_JOINTS  # 0 = rigid
    coulomb_asymmetry: tuple[float, ...] = (0.0,) * N_JOINTS
    friction_per_c: float = 0.0  # relative friction change per °C above temperature_ref_c
    temperature_ref_c: float = 25.0
    tool_warmup_c: float = 0.0
    ripple: TorqueRipple = field(default_factory=TorqueRipple)
    effort_quantum_nm: tuple[float, ...] = (0.0,) * N_JOINTS
    tool_cable: ToolCable = field(default_factory=ToolCable)

    def __post_init__(self) -> None:
        for name in ("angle_noise_rad", "zero_offset_rad", "stiffness_nm_per_rad", "coulomb_asymmetry",
                     "effort_quantum_nm"):
            object.__setattr__(self, name, _six(getattr(self, name), name))
        if any(v < 0 for v in self.angle_noise_rad + self.stiffness_nm_per_rad + self.effort_quantum_nm):
            raise ValueError("angle noise, stiffness and effort quantum must not be negative")
        if self.time_jitter_s < 0:
            raise ValueError("time_jitter_s must not be negative")
        if any(abs(a) >= 1.0 for a in self.coulomb_asymmetry):
            raise ValueError("coulomb_asymmetry must lie within (-1, 1)")

    # -- pieces SimRobot asks for -------------------------------------------------------------
    # (asked every tick of every simulated arm; the effects are frozen, so what depends on them alone is computed
    # once per instance: cached_property)
    @cached_property
    def compliance_rad_per_nm(self) -> np.ndarray:
        k = np.asarray(self.stiffness_nm_per_rad)
        out = np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), 0.0)
        out.flags.writeable = False  # shared by every tick
        return out

    @cached_property
    def zero_offset(self) -> np.ndarray:
        """``zero_offset_rad`` as an array (the tuple is converted once, not every tick)."""
        out = np.asarray(self.zero_offset_rad, float)
        out.flags.writeable = False
        return out

    @cached_property
    def elastic(self) -> bool:
        return any(k > 0 for k in self.stiffness_nm_per_rad)

    @cached_property
    def _quanta(self) -> np.ndarray | None:
        """The effort quanta, None when no joint has one (``quantise`` then returns the effort as it is)."""
        qn = np.asarray(self.effort_quantum_nm)
        return qn if qn.any() else None

    @cached_property
    def _angle_noise(self) -> np.ndarray | None:
        sigma = np.asarray(self.angle_noise_rad)
        return sigma if sigma.any() else None

    def friction_factor(self, temperature_c: np.ndarray) -> np.ndarray:
        """Relative friction at these joint temperatures (never below 10 % of the reference)."""
        return np.maximum(0.1, 1.0 + self.friction_per_c * (np.asarray(temperature_c) - self.temperature_ref_c))

    def quantise(self, tau: np.ndarray) -> np.ndarray:
        qn = self._quanta
        if qn is None:
            return tau
        return np.where(qn > 0, np.round(tau / np.where(qn > 0, qn, 1.0)) * qn, tau)

    def jitter(self, rng: np.random.Generator, tick_s: float) -> float:
        """Timestamp error of one sample: Gaussian, clipped to ±0.4 tick so stamps stay in order."""
        if self.time_jitter_s <= 0:
            return 0.0
        bound = 0.4 * tick_s  # (min/max of floats: np.clip's value, without its 5 µs of dispatch per tick)
        return float(min(max(rng.normal(0.0, self.time_jitter_s), -bound), bound))

    def angle_noise(self, rng: np.random.Generator) -> np.ndarray:
        sigma = self._angle_noise
        return rng.normal(0.0, 1.0, N_JOINTS) * sigma if sigma is not None else np.zeros(N_JOINTS)


def ripple_phases(seed: int | None) -> np.ndarray:
    """(6, 2) ripple phases of one simulated arm, fixed by its seed."""
    return np.random.default_rng([0 if seed is None else int(seed), 14]).uniform(0.0, 2 * np.pi, (N_JOINTS, 2))


def from_simulation(sim) -> PhysicsEffects:
    """The ``PhysicsEffects`` a robot YAML's ``simulation`` section asks for (``SimulationConfig``)."""
    e = getattr(sim, "effects", None)
    base = dict(angle_noise_rad=tuple(getattr(sim, "angle_noise_rad", (0.0,) * N_JOINTS)),
                time_jitter_s=float(getattr(sim, "time_jitter_s", 0.0)))
    if e is None:
        return PhysicsEffects(**base)
    return PhysicsEffects(
        **base,
        zero_offset_rad=tuple(np.radians(e.zero_offset_deg)),
        stiffness_nm_per_rad=e.stiffness_nm_per_rad,
        coulomb_asymmetry=e.coulomb_asymmetry,
        friction_per_c=e.friction_per_c,
        tool_warmup_c=e.tool_warmup_c,
        ripple=TorqueRipple(e.ripple_amplitude_nm, e.ripple_load_ratio, e.gear_ratio),
        effort_quantum_nm=e.effort_quantum_nm,
        tool_cable=ToolCable(e.cable_stiffness_nm_per_rad,
                             None if e.cable_rest_deg is None else tuple(np.radians(e.cable_rest_deg)),
                             e.cable_preload_nm),
    )


def describe(effects: PhysicsEffects) -> list[str]:
    """One short line per active effect (for logs and the benchmark header)."""
    out = []
    if any(effects.angle_noise_rad):
        out.append(f"angle noise {max(effects.angle_noise_rad):.2g} rad")
    if effects.time_jitter_s:
        out.append(f"timestamp jitter {1000 * effects.time_jitter_s:.2g} ms")
    if any(effects.zero_offset_rad):
        out.append(f"zero offsets up to {np.degrees(np.max(np.abs(effects.zero_offset_rad))):.3f}°")
    if effects.elastic:
        out.append("joint elasticity k = " + "/".join(f"{k:.3g}" for k in effects.stiffness_nm_per_rad) + " N·m/rad")
    if effects.ripple.active:
        out.append("torque ripple " + "/".join(f"{a:g}" for a in effects.ripple.amplitude_nm) + " N·m")
    if any(effects.coulomb_asymmetry):
        out.append("Coulomb asymmetry " + "/".join(f"{a:+g}" for a in effects.coulomb_asymmetry))
    if effects.friction_per_c and effects.tool_warmup_c:
        out.append(f"friction {100 * effects.friction_per_c:+g} %/°C, tool run {effects.tool_warmup_c:g} °C warmer")
    if any(effects.effort_quantum_nm):
        out.append("effort quantum " + "/".join(f"{q:g}" for q in effects.effort_quantum_nm) + " N·m")
    if effects.tool_cable.active:
        out.append("tool cable " + "/".join(f"{k:g}" for k in effects.tool_cable.stiffness_nm_per_rad) + " N·m/rad")
    return out

