"""The value types every stage shares: a sample, a sweep's name, a controller's identity and state.

They are plain frozen dataclasses with no behaviour beyond naming, so any stage may import
them without importing another stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Sample:
    """One reading of the robot: joint angles and the controller's effort signal."""

    t_ctrl: float | None  # controller timestamp in seconds, if the protocol has one
    t_recv: float  # time.monotonic() when the sample was received
    q: tuple[float, ...]  # joint angles, rad, controller convention
    effort: tuple[float, ...]  # per joint, in the driver's effort unit (Driver.effort_unit)
    # the controller's own per-joint target current (A) and model torque (N·m), where it streams them (UR)
    target_current: tuple[float, ...] | None = None
    target_moment: tuple[float, ...] | None = None


@dataclass(frozen=True)
class ControllerInfo:
    vendor: str
    model: str
    firmware: str
    serial: str = ""


@dataclass(frozen=True)
class ControllerState:
    """Whether the controller accepts motion now, and if not, what the user must do.

    Vendor mode names stay inside the driver: ``reason`` is a sentence for a person
    ("switch the teach pendant to REMOTE"), ``detail`` the raw vendor state for logs.
    """

    motion_allowed: bool
    reason: str = ""  # why motion is refused, in words a user can act on ("" when allowed)
    estop: bool = False
    protective_stop: bool = False
    moving: bool = False
    detail: str = ""


@dataclass(frozen=True)
class PayloadSetting:
    """The payload the controller uses for its own dynamics model."""

    mass_kg: float
    cog_m: tuple[float, float, float]  # in the flange frame
    tool_num: int | None = None
    # 3x3 inertia about the centre of gravity, flange axes, kg·m²; None: not given (write) / not reported (read)
    inertia_com_kgm2: tuple[tuple[float, float, float], ...] | None = None


@dataclass(frozen=True)
class FlangePose:
    """Where the controller says its flange is: position (m) and rotation matrix, base frame."""

    position_m: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...]  # 3x3, rows


@dataclass(frozen=True)
class SweepKey:
    """What a recorded sweep is: baseline matching uses all four fields."""

    pose: str
    joint: int  # 1-based
    direction: str  # "up" (elevation increasing) or "down"
    speed_percent: float

    @property
    def name(self) -> str:
        return f"{self.pose}-j{self.joint}-{self.direction}"


@dataclass
class StreamStats:
    """How the sample stream behaved over one sweep (written to the manifest).

    Holes in the data are measured on the controller's own timestamps where the protocol has
    them (a late delivery of complete data is not a hole), else on receive times; the
    largest wall-clock gap between deliveries is kept beside them.
    """

    nominal_period_s: float
    count: int = 0
    first_t: float | None = None  # receive times (monotonic)
    last_t: float | None = None
    last_ctrl_t: float | None = None
    first_ctrl_t: float | None = None  # controller time of the first sample, where the protocol stamps them
    largest_gap_s: float = 0.0  # largest step between samples (controller time where available)
    largest_wall_gap_s: float = 0.0  # largest step between deliveries (receive time)
    gaps: list[tuple[float, float]] = field(default_factory=list)  # (offset from first sample s, length s) > limit

    def add(self, t_recv: float, t_ctrl: float | None, limit_s: float) -> None:
        if self.first_t is None:
            self.first_t, self.first_ctrl_t = t_recv, t_ctrl
        elif self.last_t is not None:
            self.largest_wall_gap_s = max(self.largest_wall_gap_s, t_recv - self.last_t)
            step = (t_ctrl - self.last_ctrl_t if t_ctrl is not None and self.last_ctrl_t is not None
                    else t_recv - self.last_t)
            self.largest_gap_s = max(self.largest_gap_s, step)
            if step > limit_s:
                self.gaps.append((self.last_t - self.first_t, step))
        self.last_t, self.last_ctrl_t = t_recv, t_ctrl
        self.count += 1

    @property
    def achieved_rate_hz(self) -> float:
        if self.count < 2 or self.first_t is None or self.last_t is None or self.last_t <= self.first_t:
            return 0.0
        return (self.count - 1) / (self.last_t - self.first_t)

    @property
    def controller_rate_hz(self) -> float | None:
        """Samples per second of the controller's own clock (None where it stamps no samples)."""
        if self.count < 2 or self.first_ctrl_t is None or self.last_ctrl_t is None:
            return None
        return (self.count - 1) / max(self.last_ctrl_t - self.first_ctrl_t, 1e-9)

    def to_json(self) -> dict:
        return {"nominal_period_s": self.nominal_period_s, "count": self.count,
                "achieved_rate_hz": round(self.achieved_rate_hz, 3),
                # samples per second of the controller's clock: robot time also in a time-scaled simulation
                "controller_rate_hz": None if self.controller_rate_hz is None else round(self.controller_rate_hz, 3),
                "largest_gap_s": round(self.largest_gap_s, 6),
                "largest_wall_gap_s": round(self.largest_wall_gap_s, 6),
                "gaps": [[round(a, 6), round(b, 6)] for a, b in self.gaps]}


@dataclass(frozen=True)
class StopReport:
    """What the supervision did when it tripped: why, how fast the stop went out, whether it was heard."""

    reason: str
    fault_t: float  # monotonic time the fault was detected
    stop_sent_t: float | None  # monotonic time the first stop command went out
    acknowledged: bool
    via: str  # "command channel", "new connection", or "none"
    attempts: int = 1

    @property
    def stop_delay_s(self) -> float | None:
        return None if self.stop_sent_t is None else self.stop_sent_t - self.fault_t

    def describe(self) -> str:
        if self.stop_sent_t is None:
            return f"{self.reason}; NO stop could be sent: stop the robot at the pendant now"
        ack = "acknowledged" if self.acknowledged else "NOT acknowledged: check the robot at the pendant"
        return (f"{self.reason}; stop sent over the {self.via} {1000 * self.stop_delay_s:.0f} ms later, {ack}")

    def to_json(self) -> dict:
        return {"reason": self.reason, "stop_delay_s": self.stop_delay_s, "acknowledged": self.acknowledged,
                "via": self.via, "attempts": self.attempts}
