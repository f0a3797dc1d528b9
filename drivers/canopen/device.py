"""What the driver reads from each drive at connect beyond the communication set-up: its rated
torque or current (the effort scale) and its identity (docs/sources.md, "CANopen CiA 402")."""

from __future__ import annotations

from typing import TYPE_CHECKING

from canopen.sdo import SdoAbortedError

from payload_agent.drivers.canopen import objects as obj
from payload_agent.errors import CommunicationError, ConfigError
from payload_agent.types import ControllerInfo

if TYPE_CHECKING:
    from payload_agent.drivers.canopen.driver import CANopenDriver

RATED_MISMATCH = 0.01  # a YAML rated value more than 1 % off the drive's is refused


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
