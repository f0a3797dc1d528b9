"""The benchmark's "hard" scenarios: the realistic arm plus the error sources of a real one.

Each case's arm gets the realistic scenario's imperfections (same DH, gain and friction-drift
draws, same sensor-noise seed) plus the effects of ``payload_agent.fakes.effects``, drawn per
payload index from the magnitudes below (sources: docs/sources.md, "Physics core: error sources").

Scenarios
  hard                   realistic + every effect, with a weak tool cable
  hard-strong-cable      hard, but the tool cable is strong (moves an uncompensated result by
                         more than 10 g or 5 mm): the quality gate must refuse it
  realistic+EFFECT       ablation: realistic + that one effect (EFFECTS), to say what each costs
  realistic+cable-strong ablation: realistic + the strong cable alone

What the agent is told (the "declared" values, as a correctly configured agent would be): the
catalogue joint stiffness (the simulated arm's true stiffness is off by up to ±STIFFNESS_SPREAD) and
the zero-offset standard uncertainty ZERO_OFFSET_STD_DEG. Nothing about ripple, asymmetry,
temperature, quantisation or the cable: those must show in σ or in the gate.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

EFFECTS = ("angle_noise", "jitter", "zero_offset", "elasticity", "ripple", "asymmetry", "temperature",
           "quantisation", "cable")
HARD = "hard"
STRONG = "hard-strong-cable"
HARD_SCENARIOS = (HARD, STRONG)
ABLATION_SCENARIOS = tuple(f"realistic+{e}" for e in EFFECTS) + ("realistic+cable-strong",)

# -- magnitudes (docs/sources.md, "Physics core: error sources") -----------------------------------------
ANGLE_NOISE_RAD = 1e-5  # reported joint angle, standard deviation
JITTER_S = 1e-4  # controller timestamp, standard deviation (±100 µs on a non-real-time cyclic loop)
ZERO_OFFSET_STD_DEG = 0.02  # encoder zeroing: "a few hundredths of a degree"
# harmonic-drive torsional stiffness: CSG-32 catalogue K1/K2/K3 = 6.7e4/1.1e5/1.2e5 N·m/rad (verified),
# scaled by size³ to the EC66's gear sizes (about 25 for joints 1–3, 14 for joints 4–6), K1 region
STIFFNESS_NM_PER_RAD = (3.0e4, 3.0e4, 3.0e4, 5.5e3, 5.5e3, 5.5e3)
STIFFNESS_SPREAD = 0.2  # the true stiffness: catalogue × uniform(1 ± this) ("an average of numerous tests")
RIPPLE_NM = (0.3, 0.3, 0.3, 0.05, 0.05, 0.05)  # gear-mesh ripple amplitude at no load
RIPPLE_LOAD_RATIO = 0.01  # + 1 % of the torque through the gear
ASYMMETRY_MAX = 0.15  # Coulomb friction +/- direction: uniform ±15 % per joint
DRIFT = 0.10  # the realistic scenario's friction drift between the runs (benchmarks/cases.py), uniform ±this
FRICTION_PER_C = -0.01  # −1 % friction per °C warmer (grease viscosity)
WARMUP_MAX_C = 10.0  # tool run warmer than the baseline by uniform 0–10 °C (the baseline check's limit)
EC66_RATED_NM = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
QUANTUM_NM = tuple(r / 1000.0 for r in EC66_RATED_NM)  # one per mille of rated torque
# tool cable on joints 4–6 (N·m/rad), relaxed where the tool is mounted; per-case uniform(0.5, 1) × this
CABLE_WEAK_NM_PER_RAD = (0.02, 0.02, 0.02)
CABLE_STRONG_NM_PER_RAD = (0.3, 0.3, 0.3)


def effects_of(scenario: str) -> tuple[frozenset[str], str] | None:
    """(the effects, "weak" | "strong" cable) of a hard or ablation scenario; None for the others."""
    if scenario == HARD:
        return frozenset(EFFECTS), "weak"
    if scenario == STRONG:
        return frozenset(EFFECTS), "strong"
    if scenario == "realistic+cable-strong":
        return frozenset({"cable"}), "strong"
    if scenario.startswith("realistic+") and scenario.split("+", 1)[1] in EFFECTS:
        return frozenset({scenario.split("+", 1)[1]}), "weak"
    return None


@dataclasses.dataclass(frozen=True)
class Declared:
    """What a correctly configured agent declares about this simulated arm."""

    stiffness_nm_per_rad: tuple[float, ...] | None  # None: rigid (no compensation)
    stiffness_rel_std: float
    zero_offset_std_rad: float
    # standard uncertainty of the Coulomb friction's direction asymmetry (robot.friction_asymmetry_percent);
    # the agent measures the friction change between the runs it multiplies (evaluation/systematics/)
    friction_asymmetry_std: float = 0.0
    # standard uncertainty of the friction level's change between the runs, relative (robot.friction_change_percent)
    friction_change_std: float = 0.0
    # robot.tool_cable_fitted: True, the cell's integrator knows a cable is on the tool; None, not declared (a benchmark
    # arm's user is not assumed to know); False, declared that none is (benchmarks.wrist_null's "declared none")
    tool_cable_fitted: bool | None = None


def draw(scenario: str, index: int):
    """(PhysicsEffects for the tool run, PhysicsEffects for the calibration reference run, Declared) or None.

    The reference payload is a calibration weight: no cable; its run has its own warm-up draw.
    """
    from payload_agent.fakes.effects import PhysicsEffects, ToolCable, TorqueRipple

    spec = effects_of(scenario)
    if spec is None:
        return None
    effects, cable = spec
    rng = np.random.default_rng([index, 14, 7])  # independent of the realistic scenario's draws
    on = effects.__contains__
    # every draw is made whether or not the effect is on, so one effect's values are the same in
    # every scenario that has it
    zero = rng.normal(0.0, math.radians(ZERO_OFFSET_STD_DEG), 6)
    k_true = np.asarray(STIFFNESS_NM_PER_RAD) * rng.uniform(1 - STIFFNESS_SPREAD, 1 + STIFFNESS_SPREAD, 6)
    asym = rng.uniform(-ASYMMETRY_MAX, ASYMMETRY_MAX, 6)
    warm_tool, warm_ref = rng.uniform(0.0, WARMUP_MAX_C, 2)
    k_cable = np.asarray(CABLE_STRONG_NM_PER_RAD if cable == "strong" else CABLE_WEAK_NM_PER_RAD)
    k_cable = k_cable * rng.uniform(0.5, 1.0, 3)
    tool = PhysicsEffects(
        angle_noise_rad=ANGLE_NOISE_RAD if on("angle_noise") else 0.0,
        time_jitter_s=JITTER_S if on("jitter") else 0.0,
        zero_offset_rad=zero if on("zero_offset") else 0.0,
        stiffness_nm_per_rad=k_true if on("elasticity") else 0.0,
        coulomb_asymmetry=asym if on("asymmetry") else 0.0,
        friction_per_c=FRICTION_PER_C if on("temperature") else 0.0,
        tool_warmup_c=float(warm_tool) if on("temperature") else 0.0,
        ripple=TorqueRipple(RIPPLE_NM, RIPPLE_LOAD_RATIO) if on("ripple") else TorqueRipple(),
        effort_quantum_nm=QUANTUM_NM if on("quantisation") else 0.0,
        tool_cable=ToolCable(k_cable) if on("cable") else ToolCable(),
    )
    reference = dataclasses.replace(tool, tool_cable=ToolCable(),
                                    tool_warmup_c=float(warm_ref) if on("temperature") else 0.0)
    # friction change between the baseline and the tool run: the realistic drift (uniform ±10 %) and,
    # with the temperature effect, the warm-up (uniform 0–10 °C × 1 %/°C): root mean square
    change = math.sqrt(DRIFT ** 2 / 3.0 + ((WARMUP_MAX_C * FRICTION_PER_C) ** 2 / 3.0 if on("temperature") else 0.0))
    declared = Declared(STIFFNESS_NM_PER_RAD if on("elasticity") else None, STIFFNESS_SPREAD / math.sqrt(3.0),
                        math.radians(ZERO_OFFSET_STD_DEG) if on("zero_offset") else 0.0,
                        ASYMMETRY_MAX / math.sqrt(3.0) if on("asymmetry") else 0.0, change,
                        True if on("cable") else None)  # without the cable: nothing declared, as before session 26
    return tool, reference, declared
