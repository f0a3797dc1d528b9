"""UR robot, safety and runtime codes, and what a user must do about each: the vendor words stay here.

Codes: ur_rtde 1.6 headers and UR's RTDE guide (docs/sources.md, "UR / ur_rtde").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from payload_agent.errors import CommunicationError
from payload_agent.types import ControllerState

ROBOT_MODE_RUNNING = 7
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
                    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
SAFETY_MODE_NAMES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                     6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                     10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                     13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
RUNTIME_NAMES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED", 5: "RESUMING"}
RUNTIME_PLAYING = 2
# safety_status_bits bit numbers (ur_rtde rtde_control_interface.h enum SafetyStatus)
BIT_PROTECTIVE, BIT_RECOVERY, BIT_SAFEGUARD, BIT_SYS_ESTOP, BIT_ROBOT_ESTOP, BIT_ESTOP = 2, 3, 4, 5, 6, 7
BIT_VIOLATION, BIT_FAULT = 8, 9
ESTOP_BITS = (1 << BIT_ESTOP) | (1 << BIT_ROBOT_ESTOP) | (1 << BIT_SYS_ESTOP)
# actual_digital_input_bits (UR RTDE guide): bits 0-7 standard DI0-7, 8-15 configurable CI0-7, 16-17 tool TI0-1
DIGITAL_INPUT_NAMES = [f"DI{i}" for i in range(8)] + [f"CI{i}" for i in range(8)] + ["TI0", "TI1"]

KNOWN_SAFETY_BITS = (1 << 11) - 1  # bits 0-10 (ur_rtde enum SafetyStatus)


def corrupt_status(robot_mode: int, safety_mode: int, bits: int, runtime: int) -> str:
    """What in a package's status fields no UR controller sends (corrupt RTDE data), or ""."""
    if robot_mode not in ROBOT_MODE_NAMES:
        return f"robot_mode {robot_mode}"
    if safety_mode not in SAFETY_MODE_NAMES:
        return f"safety_mode {safety_mode}"
    if bits & ~KNOWN_SAFETY_BITS:
        return f"safety_status_bits {bits:#x}"
    if runtime not in RUNTIME_NAMES:
        return f"runtime_state {runtime}"
    return ""


@dataclass(frozen=True)
class URStatus:
    """The controller's status fields as one RTDE package of the receive interface brings them."""

    robot_mode: int
    safety_mode: int
    bits: int  # safety_status_bits
    runtime: int  # runtime_state

    @classmethod
    def read(cls, r: Any, host: str) -> "URStatus":
        """Read them from ur-rtde's ``RTDEReceiveInterface`` ``r``; CommunicationError when they hold values no UR
        controller sends (corrupt RTDE data parses into numbers: not a safety stop, a broken stream)."""
        st = cls(r.getRobotMode(), r.getSafetyMode(), r.getSafetyStatusBits(), r.getRuntimeState())
        corrupt = corrupt_status(st.robot_mode, st.safety_mode, st.bits, st.runtime)
        if corrupt:
            raise CommunicationError(f"the RTDE stream from {host} sent {corrupt}, which no UR controller sends: "
                                     "the data is corrupt")
        return st


_POWER_HINT = "power the arm on and release the brakes (teach pendant, or the dashboard's 'power on' and " \
              "'brake release')"


def safety_stop(bits: int, safety_mode: int | None = None) -> str:
    """What the safety system is doing, as an instruction; "" when it allows motion."""
    if bits & ESTOP_BITS:
        return f"the emergency stop is active: release it, then {_POWER_HINT}"
    if bits & (1 << BIT_PROTECTIVE):
        return ("the robot is in a protective stop: remove its cause, then unlock it at the teach pendant "
                "(or the dashboard's 'unlock protective stop', at least 5 s after it occurred)")
    if bits & (1 << BIT_SAFEGUARD):
        return "a safeguard stop is active: close the safeguard (the safety input that stopped it)"
    if bits & ((1 << BIT_VIOLATION) | (1 << BIT_FAULT) | (1 << BIT_RECOVERY)):
        mode = SAFETY_MODE_NAMES.get(safety_mode or 0, "a fault")
        return f"the safety system reports {mode}: clear it at the teach pendant (restart safety)"
    return ""


def refusal(robot_mode: int, safety_mode: int, bits: int, remote: bool | None) -> str:
    """Why the controller will not take a motion command now, as an instruction; "" if it will."""
    stop = safety_stop(bits, safety_mode)
    if stop:
        return stop
    if robot_mode != ROBOT_MODE_RUNNING:
        if robot_mode in (3, 4, 5):  # POWER_OFF, POWER_ON, IDLE
            return f"the arm is not ready ({'powered off' if robot_mode == 3 else 'brakes engaged'}): {_POWER_HINT}"
        return (f"the controller is not ready for motion (robot mode "
                f"{ROBOT_MODE_NAMES.get(robot_mode, robot_mode)}): wait for it or check the teach pendant")
    if remote is False:
        return ("the teach pendant is in Local control: switch it to Remote Control (the mode switch at the top "
                "right of the pendant; enable Remote Control in Settings > System first)")
    return ""


def controller_state(robot_mode: int, safety_mode: int, bits: int, runtime: int, moving: bool,
                     remote: bool | None) -> ControllerState:
    reason = refusal(robot_mode, safety_mode, bits, remote)
    control = {True: "remote", False: "local", None: "unknown"}[remote]
    detail = (f"robot_mode={ROBOT_MODE_NAMES.get(robot_mode, robot_mode)}, "
              f"safety_mode={SAFETY_MODE_NAMES.get(safety_mode, safety_mode)}, "
              f"runtime_state={RUNTIME_NAMES.get(runtime, runtime)}, control={control}")
    return ControllerState(motion_allowed=not reason, reason=reason, estop=bool(bits & ESTOP_BITS),
                           protective_stop=bool(bits & ((1 << BIT_PROTECTIVE) | (1 << BIT_SAFEGUARD))),
                           moving=moving, detail=detail)


def runtime_name(runtime: int) -> str:
    return RUNTIME_NAMES.get(runtime, str(runtime))
