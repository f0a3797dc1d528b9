"""What a robot YAML declares about its joints' systematic errors: stiffness, zero offsets, friction, a tool cable.

``robot.kinematics`` holds the joint declarations, ``robot`` the friction ones and whether a tool cable is fitted;
``evaluation.systematics`` turns them into terms of the reported σ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from payload_agent.configuration.yamlcheck import Node

N_JOINTS = 6
# A real arm's joints (docs/sources.md "Physics core: error sources"): a strain-wave gear's catalogue stiffness is
# "an average of numerous tests", ±20 % uniform: 20/√3 = 11.5 % standard uncertainty; encoder zeroing leaves "a few
# hundredths of a degree"; Coulomb friction differs by direction by up to ±15 % (uniform): 15/√3 = 8.7 %
DEFAULT_STIFFNESS_UNCERTAINTY_PERCENT = 12.0
DEFAULT_ZERO_OFFSET_UNCERTAINTY_DEG = 0.02
DEFAULT_FRICTION_ASYMMETRY_PERCENT = 8.7
# how much a joint's friction level may change between the baseline and the tool run in a way the net
# change the data show does not reveal (components changing in opposite directions: Coulomb friction
# falls as the joints warm up, load-dependent friction rises with the tool's weight): a ±10 % drift
# and a warm-up within storage.baseline_max_temperature_delta_c at about −1 %/°C, each uniform: √(2·10²/3) ≈ 8 %
DEFAULT_FRICTION_CHANGE_PERCENT = 8.0
MIN_STIFFNESS_NM_PER_RAD = 100.0  # softer than this twists a joint by 0.6° per N·m: a unit mistake


@dataclass(frozen=True)
class JointSystematicsConfig:
    """What the robot YAML declares about its joints' systematic errors (``evaluation.systematics``):
    ``robot.kinematics.stiffness_nm_per_rad`` (absent: rigid), ``stiffness_uncertainty_percent``,
    ``zero_offset_uncertainty_deg``, ``robot.friction_asymmetry_percent``, ``robot.friction_change_percent``, in SI /
    fractions (standard deviations). The zeros' correlation and their coupling to the drive gains ([i][j]: joint j's
    relative effort change that goes with joint i's angles shifted by 1 rad) exist only where a calibration measured
    the zeros (``evaluation.zero_offsets.declaration``), never in YAML; None: independent, uncoupled."""
    stiffness_nm_per_rad: tuple[float, ...] | None = None  # None, or 0 on a joint: rigid, not compensated
    stiffness_rel_std: float = DEFAULT_STIFFNESS_UNCERTAINTY_PERCENT / 100.0
    zero_offset_std_rad: tuple[float, ...] = (math.radians(DEFAULT_ZERO_OFFSET_UNCERTAINTY_DEG),) * N_JOINTS
    friction_asymmetry_std: float = DEFAULT_FRICTION_ASYMMETRY_PERCENT / 100.0  # of the Coulomb level, by direction
    friction_change_std: float = DEFAULT_FRICTION_CHANGE_PERCENT / 100.0  # of the baseline's friction level
    zero_offset_corr: tuple[tuple[float, ...], ...] | None = None  # 6×6
    zero_gain_coupling: tuple[tuple[float, ...], ...] | None = None  # 6×6
    # robot.tool_cable_fitted: True, a cable or hose runs to the tool (its effect comes off θ̂); False, declared that
    # none does (no cable term in σ unless the presence test contradicts it); None, not declared (the test decides)
    tool_cable_fitted: bool | None = None

    @property
    def tool_cable_absent(self) -> bool:
        """The YAML says explicitly that no cable or hose runs to the tool (``tool_cable_fitted: false``)."""
        return self.tool_cable_fitted is False


def joint_systematics(kin: Node, robot: Node | None) -> JointSystematicsConfig:
    """The optional stiffness, zero-offset and friction declarations (see JointSystematicsConfig)."""
    stiffness = None
    if kin.has("stiffness_nm_per_rad") and kin.data["stiffness_nm_per_rad"] is not None:
        stiffness = kin.per_joint("stiffness_nm_per_rad", N_JOINTS, min=0, max=1e9)
        soft = [i for i, k in enumerate(stiffness) if 0 < k < MIN_STIFFNESS_NM_PER_RAD]
        if soft:
            raise kin.error(f"stiffness_nm_per_rad[{soft[0]}]",
                            f"{stiffness[soft[0]]:g} N·m/rad is implausibly soft for a robot joint (at least "
                            f"{MIN_STIFFNESS_NM_PER_RAD:g}; 0 means rigid): is it in N·m/deg or N·m/arcmin?")
        if not any(stiffness):
            stiffness = None
    stiff_pct = kin.number("stiffness_uncertainty_percent", DEFAULT_STIFFNESS_UNCERTAINTY_PERCENT, min=0, max=100)
    zero_deg = kin.per_joint("zero_offset_uncertainty_deg", N_JOINTS, DEFAULT_ZERO_OFFSET_UNCERTAINTY_DEG,
                             min=0, max=5)
    asym_pct, change_pct = DEFAULT_FRICTION_ASYMMETRY_PERCENT, DEFAULT_FRICTION_CHANGE_PERCENT
    if robot is not None:
        asym_pct = robot.number("friction_asymmetry_percent", DEFAULT_FRICTION_ASYMMETRY_PERCENT, min=0, max=100)
        change_pct = robot.number("friction_change_percent", DEFAULT_FRICTION_CHANGE_PERCENT, min=0, max=100)
    cable = None if robot is None else tool_cable(robot)
    return JointSystematicsConfig(stiffness, stiff_pct / 100.0, tuple(math.radians(v) for v in zero_deg),
                                  asym_pct / 100.0, change_pct / 100.0, tool_cable_fitted=cable)


def tool_cable(robot: Node) -> bool | None:
    """``robot.tool_cable_fitted``: true, false (declared: no cable or hose to the tool) or absent (None: not declared,
    the cable's presence test decides). Three states, so "no" or 0 is refused rather than read as one of them."""
    value = robot.raw("tool_cable_fitted", None)
    if value is not None and not isinstance(value, bool):
        raise robot.error("tool_cable_fitted", f"expected true (a cable or hose runs to the tool), false (none does) "
                                               f"or no value (not declared: the data decide), got {value!r}")
    return value
