"""A move request checked before anything goes to the controller: a finite target of the arm's joint count,
a positive speed, acceleration and timeout, a speed within the robot's limit and the driver's move command's
(``DriverOptions.command_limits``, the same the safety gate checks the plan against). Every driver gets these checks from the base class, so none writes them again; the
safety gate has checked the plan already, and this is the last line before a command leaves the agent."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from payload_agent.drivers.settings import CommandLimits, MotionLimits
from payload_agent.errors import MotionAbortedError, SafetyError


def as_joint_vector(values: Sequence[float], n: int = 6) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"expected {n} joint values, got shape {arr.shape}")
    return arr


def checked_request(target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float, timeout_s: float,
                    limits: MotionLimits, command: CommandLimits) -> tuple[np.ndarray, float, float, float]:
    """(target, speed, acceleration, timeout) as numbers; MotionAbortedError for a malformed request,
    SafetyError for one beyond the robot's speed limit or the move command's (``command``). Nothing has been
    sent either way."""
    target = as_joint_vector(target_rad, limits.n_joints)
    if not np.all(np.isfinite(target)):
        raise MotionAbortedError(f"move target {target.tolist()} is not finite; nothing was sent")
    for what, v in (("speed", speed_rad_s), ("acceleration", accel_rad_s2), ("timeout", timeout_s)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise MotionAbortedError(f"move {what} {v!r} is not a positive number; nothing was sent")
    if speed_rad_s > limits.max_joint_speed_rad_s * (1 + 1e-9):  # the safety gate's own tolerance
        raise SafetyError(f"joint speed {speed_rad_s} rad/s above the robot's {limits.max_joint_speed_rad_s} rad/s "
                          "(robot.max_joint_speed_deg_s); nothing was sent")
    if command.max_joint_speed_rad_s is not None and speed_rad_s > command.max_joint_speed_rad_s:
        raise SafetyError(f"joint speed {speed_rad_s} rad/s above the {command.max_joint_speed_rad_s} rad/s the move "
                          f"command accepts ({command.source}); nothing was sent")
    if command.max_joint_accel_rad_s2 is not None and accel_rad_s2 > command.max_joint_accel_rad_s2:
        raise SafetyError(f"joint acceleration {accel_rad_s2} rad/s² above the {command.max_joint_accel_rad_s2} rad/s² "
                          f"the move command accepts ({command.source}); nothing was sent")
    return target, float(speed_rad_s), float(accel_rad_s2), float(timeout_s)
