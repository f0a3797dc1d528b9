"""The settings every driver takes: its options' common base, the robot's motion limits and the
supervision's limits. Plain data, so the configuration can build them without a client library."""

from __future__ import annotations

from dataclasses import dataclass

from typing import Any, ClassVar

from payload_agent.configuration.options import option, parse_options


@dataclass(frozen=True)
class CommandLimits:
    """What one move command of a driver accepts at most: its client library or controller refuses more.

    Declared per driver family (``DriverOptions.command_limits``), checked by the safety gate on the whole
    plan before the first move, so a move above them is refused by name there, not by the controller mid-run.
    None: no limit of the driver's own (the robot YAML's maxima still apply)."""

    max_joint_speed_rad_s: float | None = None
    max_joint_accel_rad_s2: float | None = None
    source: str = ""  # where the limit is documented (docs/sources.md)


@dataclass(frozen=True, kw_only=True)
class DriverOptions:
    """Options every driver has; each driver subclasses this with its own fields."""

    command_limits: ClassVar[CommandLimits] = CommandLimits()  # the driver family's own move-command limits

    @classmethod
    def parse(cls, data: Any, key_path: str = "driver", source: str | None = None) -> "DriverOptions":
        """The YAML ``driver`` mapping -> these options (ConfigError names the key). A family whose fields
        depend on each other overrides this; it never imports the family's client library."""
        return parse_options(cls, data, key_path, source)

    type: str = option(help="the driver name (registry key)")
    serial: str | None = option(None, help="the controller's serial number as its type plate shows it: identifies "
                                           "the robot (stored baseline) where the controller does not report one, "
                                           "and must match where it does")
    target_tolerance_deg: float | None = option(None, gt=0, max=10.0,
                                                help="final position check after a move: the arm must stand this "
                                                     "close to every joint's target (default: the driver's)")


@dataclass(frozen=True)
class MotionLimits:
    """What a driver needs from the robot section to command PTP moves."""

    max_joint_speed_rad_s: float
    max_joint_accel_rad_s2: float
    n_joints: int = 6


@dataclass(frozen=True)
class Supervision:
    """Watchdog settings (the robot YAML's ``safety`` section)."""

    max_stream_gap_s: float | None = None  # None: max(5 sample periods, 50 ms)
    stop_ack_timeout_s: float = 2.0
    # a driver that polls its controller during a move (command_ok()) trips when no reply came for this long
    max_reply_wait_s: float = 0.3
    # the arm has stood at the move's target this long and the controller still has not reported it finished
    finish_grace_s: float = 0.5
