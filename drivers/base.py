"""The driver contract: the only way payload-agent talks to a controller.

A driver knows one protocol family. It never sees a plan or a least-squares
matrix; it moves, streams samples and reports state. Only the safety gate calls
``move_joints`` (see ``payload_agent.safety``).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np


@dataclass(frozen=True)
class Sample:
    """One reading of the robot: joint angles and the controller's effort signal."""

    t_ctrl: float | None  # controller timestamp in seconds, if the protocol has one
    t_recv: float  # time.monotonic() when the sample was received
    q: tuple[float, ...]  # joint angles, rad, controller convention
    effort: tuple[float, ...]  # per joint, in the controller's own unit (see Driver.effort_unit)


@dataclass(frozen=True)
class ControllerInfo:
    vendor: str
    model: str
    firmware: str
    serial: str = ""


@dataclass(frozen=True)
class ControllerState:
    """What decides whether the robot may move now."""

    mode: str  # e.g. "remote", "teach", "play", "automatic"
    servo_on: bool
    estop: bool
    protective_stop: bool
    moving: bool = False
    detail: str = ""

    @property
    def fault(self) -> str | None:
        """A sentence saying why the robot must not move, or None."""
        if self.estop:
            return "emergency stop is active"
        if self.protective_stop:
            return "protective stop is active"
        if not self.servo_on:
            return "servos are off"
        return None


@dataclass(frozen=True)
class PayloadSetting:
    """The payload the controller uses for its own dynamics model."""

    mass_kg: float
    cog_m: tuple[float, float, float]  # in the flange frame
    tool_num: int | None = None


SampleSink = Callable[[Sample], None]


class Driver(abc.ABC):
    """One controller connection.

    Subclasses set ``name`` (the registry key used in the YAML ``driver.type``)
    and ``effort_unit`` (the unit of ``Sample.effort``: "percent_rated", "A", "Nm", ...).
    """

    name: ClassVar[str] = ""
    effort_unit: ClassVar[str] = ""

    def __init__(self, options: Mapping[str, Any], *, max_joint_speed_rad_s: float, key_path: str = "driver"):
        """``options`` is the YAML ``driver`` mapping; subclasses validate it and raise ConfigError."""
        self.options = dict(options)
        self.max_joint_speed_rad_s = float(max_joint_speed_rad_s)
        self.key_path = key_path

    # -- connection -------------------------------------------------------------------------
    @abc.abstractmethod
    def connect(self) -> None:
        """Open every socket the driver needs; raise CommunicationError naming host and port."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release sockets and threads. Never raises."""

    @abc.abstractmethod
    def identify(self) -> ControllerInfo: ...

    @abc.abstractmethod
    def state(self) -> ControllerState: ...

    # -- motion -----------------------------------------------------------------------------
    @abc.abstractmethod
    def move_joints(self, target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                    timeout_s: float) -> None:
        """One PTP joint move; returns when the controller reports it finished at the target.

        ``speed_rad_s`` caps the leading joint's speed, ``accel_rad_s2`` its acceleration.
        Raises MotionAbortedError on any abnormal end (stop, fault, timeout, target missed).
        """

    @abc.abstractmethod
    def stop(self) -> None:
        """Halt motion now. Best effort: never raises."""

    # -- sampling ---------------------------------------------------------------------------
    @abc.abstractmethod
    def start_stream(self, sink: SampleSink) -> None:
        """Deliver every sample at the controller's native rate to ``sink`` (from a thread)."""

    @abc.abstractmethod
    def stop_stream(self) -> None: ...

    @property
    def stream_error(self) -> BaseException | None:
        """The error that ended the sample stream, if it ended on its own."""
        return None

    # -- optional capabilities -------------------------------------------------------------
    def read_payload(self) -> PayloadSetting:
        from payload_agent.errors import UnsupportedCapability

        raise UnsupportedCapability(f"driver {self.name!r} cannot read the payload setting")

    def write_payload(self, payload: PayloadSetting) -> None:
        from payload_agent.errors import UnsupportedCapability

        raise UnsupportedCapability(f"driver {self.name!r} cannot write the payload setting")

    def read_digital_input(self, index: int) -> bool:
        """State of the controller's general-purpose digital input ``index`` (for `watch`)."""
        from payload_agent.errors import UnsupportedCapability

        raise UnsupportedCapability(f"driver {self.name!r} cannot read digital inputs")

    def joint_temperatures_c(self) -> tuple[float, ...] | None:
        """Per-joint temperatures in °C as the controller reports them, or None if it does not."""
        return None

    # -- context manager --------------------------------------------------------------------
    def __enter__(self) -> "Driver":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def as_joint_vector(values: Sequence[float], n: int = 6) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"expected {n} joint values, got shape {arr.shape}")
    return arr
