"""Elite EC mode and state codes, and what a user must do about each: the vendor words stay here.

Codes from Elite's own library (``BaseEC.RobotMode``, ``BaseEC.RobotState``, ``BaseEC.RobotType``);
docs/sources.md, "Elite EC".
"""

from __future__ import annotations

MODE_TEACH, MODE_PLAY, MODE_REMOTE = 0, 1, 2
MODE_NAMES = {MODE_TEACH: "teach", MODE_PLAY: "play", MODE_REMOTE: "remote"}
STATE_STOP, STATE_PAUSE, STATE_ESTOP, STATE_RUNNING, STATE_ERROR, STATE_COLLISION = range(6)
STATE_NAMES = {0: "stopped", 1: "paused", 2: "emergency stop", 3: "running", 4: "error/alarm", 5: "collision"}
SUBTYPE_MODELS = {3: "EC63", 6: "EC66", 12: "EC612"}


def refusal(mode: int, servo: bool, estop: bool, rstate: int) -> str:
    """Why the controller will not take a motion command now, as an instruction; "" if it will."""
    if mode != MODE_REMOTE:
        return (f"the Elite controller is in {MODE_NAMES.get(mode, f'unknown ({mode})')} mode: turn the teach "
                "pendant's mode key to REMOTE, then try again")
    if estop:
        return ("the emergency stop is pressed: release it, clear the alarm on the pendant (or clearAlarm), "
                "switch the servos on, then try again")
    if rstate in (STATE_ERROR, STATE_COLLISION):
        return (f"the robot is in {STATE_NAMES[rstate]} state: clear the alarm on the pendant (or clearAlarm), "
                "switch the servos on, then try again")
    if rstate == STATE_RUNNING:
        return "the robot is already running a motion: wait for it to finish or stop it"
    if rstate == STATE_PAUSE:
        return "the robot is paused: stop the paused program on the pendant first"
    if rstate != STATE_STOP:
        return f"the robot reports an unknown state {rstate}: check the pendant"
    if not servo:
        return ("the servos are off: switch them on (pendant, or set_servo_status 1 after clearAlarm and "
                "syncMotorStatus), then try again")
    return ""


def abort_text(rstate: int, estop: bool) -> str:
    """Why a running move ended (robot state ``rstate``; ``estop``: the emergency stop is pressed), with what to
    do. The controller shows "emergency stop" (2) only briefly before "error/alarm" (4)."""
    if estop and rstate == STATE_ERROR:
        rstate = STATE_ESTOP
    why = STATE_NAMES.get(rstate, f"state {rstate}")
    hint = {STATE_ESTOP: "release the emergency stop, clear the alarm and switch the servos on",
            STATE_COLLISION: "check for an obstacle, then clear the collision alarm",
            STATE_ERROR: "read the alarm on the pendant and clear it",
            STATE_PAUSE: "the motion was paused from the pendant"}.get(rstate, "")
    return f"the joint move was aborted: robot state {why}. {hint}".strip()
