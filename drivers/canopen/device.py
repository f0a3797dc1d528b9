"""What the driver sets and reads on each drive at connect beyond the communication set-up: its mode of
operation (profile position, the only one the driver commands), its rated torque or current (the effort
scale) and its identity (docs/sources.md, "CANopen CiA 402")."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from canopen.sdo import SdoAbortedError

from payload_agent.drivers.canopen import objects as obj
from payload_agent.drivers.canopen.cia402 import MODE_PROFILE_POSITION
from payload_agent.errors import CommunicationError, ConfigError, RobotNotReadyError
from payload_agent.types import ControllerInfo

if TYPE_CHECKING:
    from payload_agent.drivers.canopen.driver import CANopenDriver

RATED_MISMATCH = 0.01  # a YAML rated value more than 1 % off the drive's is refused


def set_profile_position_mode(drv: "CANopenDriver", j: int) -> None:
    """0x6060 = profile position, confirmed by 0x6061 within ``enable_timeout_s``: configuration (SDO), so it
    happens at connect and a move sends no SDO. Writing the mode moves nothing and powers nothing."""
    drv.sdo_write(j, obj.MODES_OF_OPERATION, MODE_PROFILE_POSITION)
    deadline = time.monotonic() + drv.options.enable_timeout_s
    while (mode := drv.sdo_read(j, obj.MODES_DISPLAY)) != MODE_PROFILE_POSITION:
        if time.monotonic() > deadline:
            raise RobotNotReadyError(f"{drv.labels[j]} does not switch to profile position mode: 0x6061 shows "
                                     f"{mode} after 0x6060 = {MODE_PROFILE_POSITION}")
        time.sleep(0.005)


def effort_scale(drv: "CANopenDriver", j: int) -> float:
    """Effort unit per per-mille: rated torque (N·m) or current (A) / 1000, or 1 for raw per mille."""
    opts = drv.options
    if opts.effort_scaling == "permille":
        return 1.0
    torque = opts.effort_object == "torque"
    index, unit, key = ((obj.RATED_TORQUE, "N·m", "rated_torque_nm") if torque else
                        (obj.RATED_CURRENT, "A", "rated_current_a"))
    yaml_values = opts.rated_torque_nm if torque else opts.rated_current_a
    try:
        drive = drv.sdo_read(j, index) / 1000.0  # mN·m / mA
    except CommunicationError as exc:
        if not isinstance(exc.__cause__, SdoAbortedError):
            raise
        drive = 0.0  # the drive has no such object
    yaml_value = None if yaml_values is None else yaml_values[j]
    if drive > 0 and yaml_value is not None and abs(yaml_value - drive) > RATED_MISMATCH * drive:
        raise ConfigError(f"driver.{key}[{j}]", f"{yaml_value:g} {unit}, but {drv.labels[j]} reports "
                                                f"{drive:g} {unit} in 0x{index:04X}: remove the YAML value or "
                                                "check which drive is which joint")
    rated = drive if drive > 0 else yaml_value
    if rated is None:
        raise ConfigError(f"driver.{key}", f"{drv.labels[j]} has no rated value in 0x{index:04X}: give "
                                           f"driver.{key} (6 values, {unit}) or set effort_scaling: permille")
    return rated / 1000.0


def identity(drv: "CANopenDriver") -> ControllerInfo:
    def text(j: int, index: int) -> str:
        try:
            return str(drv.sdo_read(j, index)).strip("\x00 ")
        except CommunicationError:
            return "?"
    serials = []
    for j in range(drv.n):
        try:
            serials.append(f"{drv.sdo_read(j, obj.IDENTITY, 4):08X}")
        except CommunicationError:
            serials.append("?")
    try:
        vendor = f"CANopen vendor-ID 0x{drv.sdo_read(0, obj.IDENTITY, 1):08X}"
    except CommunicationError:
        vendor = "CANopen"
    return ControllerInfo(vendor=vendor, model=f"{drv.n} x {text(0, obj.DEVICE_NAME)} (CiA 402)",
                          firmware=text(0, obj.SOFTWARE_VERSION), serial="/".join(serials))
