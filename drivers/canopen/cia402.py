"""The CiA 402 power state machine and profile position handshake, as the master sees it.

Statusword decoding and the controlword commands are the canopen library's own tables
(``canopen.profiles.p402.State402``); this module adds what the driver needs on top: which
command moves a drive one step towards OPERATION ENABLED, the profile position bits, and
emergency error codes in words (docs/sources.md, "CANopen CiA 402").
"""

from __future__ import annotations

from canopen.emcy import EmcyError
from canopen.profiles.p402 import State402

CW_SHUTDOWN = State402.CW_SHUTDOWN  # 0x0006: -> READY TO SWITCH ON
CW_SWITCH_ON = State402.CW_SWITCH_ON  # 0x0007: -> SWITCHED ON
CW_ENABLE_OPERATION = State402.CW_OPERATION_ENABLED  # 0x000F: -> OPERATION ENABLED
CW_QUICK_STOP = State402.CW_QUICK_STOP  # 0x0002: OPERATION ENABLED -> QUICK STOP ACTIVE (others -> SWITCH ON DISABLED)
CW_DISABLE_VOLTAGE = State402.CW_DISABLE_VOLTAGE  # 0x0000: -> SWITCH ON DISABLED
CW_FAULT_RESET = 0x0080  # bit 7, acts on its rising edge: FAULT -> SWITCH ON DISABLED
CW_NEW_SETPOINT = 0x0010  # profile position: bit 4, a rising edge starts the set-point in 0x607A

SW_TARGET_REACHED = 1 << 10
SW_SETPOINT_ACK = 1 << 12
SW_FOLLOWING_ERROR = 1 << 13

OPERATION_ENABLED = "OPERATION ENABLED"
FAULT = "FAULT"
FAULT_REACTION = "FAULT REACTION ACTIVE"
QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
FAULTY = (FAULT, FAULT_REACTION)

MODE_PROFILE_POSITION = 1  # 0x6060 / 0x6061

# the one command that takes a drive from each state one step towards OPERATION ENABLED
_ENABLE_STEP = {
    "SWITCH ON DISABLED": CW_SHUTDOWN,
    "READY TO SWITCH ON": CW_SWITCH_ON,
    "SWITCHED ON": CW_ENABLE_OPERATION,
    QUICK_STOP_ACTIVE: CW_DISABLE_VOLTAGE,  # leave quick stop through SWITCH ON DISABLED, never straight back
}

# emergency error codes the driver names more precisely than the CiA 301 class (docs/sources.md)
_CODES = {
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x8110: "CAN overrun",
    0x8120: "CAN in error passive",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8611: "following error",
}


def state_of(statusword: int) -> str:
    """The CiA 402 state a statusword shows ("OPERATION ENABLED", "FAULT", ...)."""
    for name, (mask, value) in State402.SW_MASK.items():
        if statusword & mask == value:
            return name
    return f"UNKNOWN (statusword 0x{statusword:04X})"


def enable_step(state: str) -> int | None:
    """The controlword for the next step towards OPERATION ENABLED; None if there is none (FAULT, ...)."""
    return _ENABLE_STEP.get(state)


def stopped(state: str) -> bool:
    """Whether a drive in this state no longer follows a motion command (a quick stop took effect)."""
    return state != OPERATION_ENABLED


def describe_code(code: int) -> str:
    """An emergency / 0x603F error code in words: "0x8611 (following error)"."""
    text = _CODES.get(code) or EmcyError(code, 0, b"", 0.0).get_desc() or "manufacturer specific"
    return f"0x{code:04X} ({text})"
