"""The ``driver`` section of a robot YAML for the UR driver, as a typed dataclass.

Parsed by ``configuration.options.parse_options`` (through ``Driver.parse_options``), so
``plan`` checks it without connecting and a mistake names its key (``driver.frequency_hz``).

    driver:
      type: ur_rtde
      host: 192.168.1.10          # required
      frequency_hz: 500           # optional: default 500 on e-Series, 125 on CB3
      connect_timeout_s: 5.0      # reachability check before ur-rtde's own (blocking) connect
      upper_range_registers: false  # ur-rtde's FLAG_UPPER_RANGE_REGISTERS (registers 24..47)
      target_tolerance_deg: 0.1   # final position check after a move
      stop_decel_rad_s2: 2.0      # stopJ deceleration used by stop() and aborted moves
"""

from __future__ import annotations

from dataclasses import dataclass

from typing import ClassVar

from payload_agent.drivers.base import DriverOptions, option
from payload_agent.drivers.settings import CommandLimits


@dataclass(frozen=True, kw_only=True)
class URRTDEOptions(DriverOptions):
    # ur-rtde's RTDEControlInterface::moveJ refuses a speed above UR_JOINT_VELOCITY_MAX or an acceleration above
    # UR_JOINT_ACCELERATION_MAX (docs/sources.md, "UR / ur_rtde")
    command_limits: ClassVar[CommandLimits] = CommandLimits(3.14, 40.0, "ur-rtde's moveJ: UR_JOINT_VELOCITY_MAX, "
                                                                        "UR_JOINT_ACCELERATION_MAX")
    host: str = option(help="the controller's IP address or host name")
    frequency_hz: float | None = option(None, gt=0.0, max=500.0,
                                        help="RTDE rate; default 500 Hz on e-Series, 125 Hz on CB3")
    connect_timeout_s: float = option(5.0, gt=0.0, max=120.0,
                                      help="reachability check before ur-rtde's own (blocking) connect")
    upper_range_registers: bool = option(False, help="ur-rtde's FLAG_UPPER_RANGE_REGISTERS (registers 24..47)")
    stop_decel_rad_s2: float = option(2.0, gt=0.0, max=40.0, help="stopJ deceleration of stops and aborted moves")
