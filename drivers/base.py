"""The driver contract: the only way payload-agent talks to a controller.

A driver knows one protocol family. It never sees a plan or a least-squares matrix; it
moves, streams samples and reports state. Only the safety gate calls ``move_joints``
(see ``payload_agent.motion.safety``).

The base class does the work every protocol needs, the way python-can's ``BusABC`` does:

- the **sample stream**: a reader thread calls the driver's one hook ``_read_sample`` from
  ``connect()`` to ``close()``, keeps the newest sample, hands every sample to the sink, and
  keeps per-sweep statistics (``begin_stats`` / ``end_stats``);
- **supervision** of every move: a watchdog trips when the stream stalls for longer than
  ``gap_limit_s``, when the stream fails (garbage, NaN, closed) or when the command connection
  dies; it then stops the arm within a fraction of a second, over the command channel if it
  still lives and otherwise over a new connection, retries until the controller acknowledges
  or ``stop_ack_timeout_s`` has passed, and ``move_joints`` raises ``SupervisionTrip`` with a
  ``StopReport`` saying which happened.

A driver fills the hooks: ``_open``/``_close``, ``_read_sample``, ``_move_joints`` (which
polls ``check_supervision()`` while it waits), ``_stop_command`` and ``_stop_fresh``, and
``identify``/``state``. Its options are a typed dataclass (``options_class``) read by the
project's YAML validator, so ``plan`` checks them without connecting.
"""

from __future__ import annotations

import abc
import math
import threading
import time
from typing import Any, Callable, ClassVar, Sequence

import numpy as np

from payload_agent.configuration.options import option, parse_options
from payload_agent.drivers.settings import DriverOptions, MotionLimits, Supervision
from payload_agent.errors import (CommunicationError, ConfigError, MotionAbortedError, MotionNotFinished,
                                  MotionStopped, PayloadAgentError, SupervisionTrip, UnsupportedCapability)
from payload_agent.types import (ControllerInfo, ControllerState, FlangePose, PayloadSetting, Sample, StopReport,
                                 StreamStats)

__all__ = ["Driver", "DriverOptions", "MotionLimits", "SampleSink", "Sample", "ControllerInfo", "ControllerState",
           "PayloadSetting", "FlangePose", "as_joint_vector", "option"]

SampleSink = Callable[[Sample], None]

MIN_GAP_LIMIT_S = 0.05  # the watchdog never trips on less than this (or 5 sample periods)
AT_TARGET_RAD = math.radians(0.05)  # "the arm is at the target" for the never-finished check
WATCHDOG_TICK_S = 0.005
READ_TIMEOUT_S = 0.05  # how long one _read_sample call may block


class Driver(abc.ABC):
    """One controller connection.

    Subclasses set ``name`` (the YAML ``driver.type``), ``options_class``, ``simulator``
    ("module:Class" of the simulated controller that speaks the same protocol) and, in
    ``__init__``, ``effort_unit`` and ``nominal_period_s``.
    """

    name: ClassVar[str] = ""
    options_class: ClassVar[type[DriverOptions]] = DriverOptions
    simulator: ClassVar[str | None] = None
    reports_flange_pose: ClassVar[bool] = False  # can flange_pose() answer (kinematic cross-check)
    # whose clock paces the samples: the controller's ("controller"), or the agent's own (CANopen SYNC: "agent")
    sampling_clock: ClassVar[str] = "controller"

    def __init__(self, options: DriverOptions, limits: MotionLimits, supervision: Supervision | None = None):
        self.options = options
        self.limits = limits
        self.supervision = supervision or Supervision()
        self.effort_unit: str = ""
        self.nominal_period_s: float = 0.008
        self._sink: SampleSink | None = None
        self._sink_lock = threading.Lock()
        self._latest: Sample | None = None
        self._stream_error: BaseException | None = None
        self._reader: threading.Thread | None = None
        self._watchdog: threading.Thread | None = None
        self._running = threading.Event()
        self._stats: StreamStats | None = None
        self._stats_lock = threading.Lock()
        self._armed = False
        self._armed_since = 0.0
        self._target: np.ndarray | None = None
        self._at_target_since: float | None = None
        self._last_command_ok: float | None = None
        self._trip_error_class: type[PayloadAgentError] = SupervisionTrip
        self._trip_lock = threading.Lock()
        self._tripped = threading.Event()
        self._trip_report: StopReport | None = None
        self._connected = False
        # a move this session sent may still be running: set when a move goes out, cleared when the controller
        # reports it finished or acknowledges our stop. stop() acts only while it is set, so a session never
        # stops motion it did not command (another session's, the pendant's program).
        self._commanded = False
        self._stop_requested = threading.Event()  # stop() during our move: the move's wait ends with MotionStopped

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def parse_options(cls, data: Any, key_path: str = "driver", source: str | None = None) -> DriverOptions:
        """The YAML ``driver`` mapping -> this driver's options (ConfigError names the key)."""
        return parse_options(cls.options_class, data, key_path, source)

    def check_effort_unit(self, yaml_unit: str, key_path: str = "effort.unit") -> None:
        if yaml_unit != self.effort_unit:
            raise ConfigError(key_path, f"the {self.name} driver reports effort in {self.effort_unit!r} with these "
                                        f"driver options, but the YAML says {yaml_unit!r}; set effort.unit to "
                                        f"{self.effort_unit!r} (and its gains to N·m per {self.effort_unit})")

    @property
    def gap_limit_s(self) -> float:
        if self.supervision.max_stream_gap_s is not None:
            return self.supervision.max_stream_gap_s
        return max(5 * self.nominal_period_s, MIN_GAP_LIMIT_S)

    # -- hooks a driver fills ----------------------------------------------------------------
    @abc.abstractmethod
    def _open(self) -> None:
        """Open every connection; raise CommunicationError naming host and port."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release connections. Never raises."""

    @abc.abstractmethod
    def _read_sample(self, timeout_s: float) -> Sample | None:
        """The next sample, or None if none arrived within ``timeout_s``.

        Raise CommunicationError when the stream is broken (closed, unparsable); the base then
        ends the stream and trips the supervision.
        """

    @abc.abstractmethod
    def identify(self) -> ControllerInfo:
        """What the controller reports of itself (vendor, model, firmware, serial where it has them); never
        where it is reached (an address or port changes, the robot does not)."""

    @abc.abstractmethod
    def state(self) -> ControllerState: ...

    @abc.abstractmethod
    def _move_joints(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float, timeout_s: float) -> None:
        """One PTP move; return when the controller reports it finished at the target.

        Call ``check_supervision()`` while waiting. Raise MotionAbortedError on an abnormal end.
        """

    @abc.abstractmethod
    def _stop_command(self) -> bool:
        """Stop the arm over the existing command channel; True if the controller acknowledged."""

    def _stop_fresh(self) -> bool:
        """Stop the arm over a new connection (the old one is gone); True if acknowledged."""
        return False

    def _command_alive(self) -> bool:
        """Whether the command channel still works (cheap, no round trip)."""
        return True

    # -- connection ---------------------------------------------------------------------------
    def connect(self) -> None:
        if self._connected:
            return
        self._stream_error = None
        self._latest = None
        self._open()
        self._connected = True
        self._running.set()
        self._reader = threading.Thread(target=self._reader_loop, name=f"{self.name}-stream", daemon=True)
        self._reader.start()
        self._watchdog = threading.Thread(target=self._watchdog_loop, name=f"{self.name}-watchdog", daemon=True)
        self._watchdog.start()

    def close(self) -> None:
        """Release connections and threads. Never raises."""
        self._running.clear()
        with self._sink_lock:
            self._sink = None
        for th in (self._reader, self._watchdog):
            if th is not None and th is not threading.current_thread():
                th.join(timeout=2.0)
        self._reader = self._watchdog = None
        if self._connected:
            self._connected = False
            try:
                self._close()
            except Exception:
                pass

    def __enter__(self) -> "Driver":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- sample stream ------------------------------------------------------------------------
    def start_stream(self, sink: SampleSink) -> None:
        """Deliver every sample from now on to ``sink`` (called from the reader thread)."""
        if not self._connected:
            raise CommunicationError(f"the {self.name} driver is not connected (call connect() first)")
        if self._stream_error is not None:
            raise CommunicationError(f"the sample stream has failed: {self._stream_error}") from self._stream_error
        with self._sink_lock:
            self._sink = sink

    def stop_stream(self) -> None:
        with self._sink_lock:
            self._sink = None

    @property
    def stream_error(self) -> BaseException | None:
        """The error that ended the sample stream, if it ended on its own."""
        return self._stream_error

    @property
    def latest_sample(self) -> Sample | None:
        return self._latest

    def wait_sample(self, timeout_s: float, after: float | None = None) -> Sample:
        """The newest sample (received after ``after``, monotonic, if given); CommunicationError on none."""
        deadline = time.monotonic() + timeout_s
        while True:
            s = self._latest
            if s is not None and (after is None or s.t_recv > after):
                return s
            if self._stream_error is not None:
                raise CommunicationError(f"the sample stream ended: {self._stream_error}")
            if time.monotonic() > deadline:
                raise CommunicationError(f"no joint sample from the {self.name} controller "
                                         f"({self.describe_endpoint()}) for {timeout_s:.1f} s")
            time.sleep(0.002)

    def describe_endpoint(self) -> str:
        """Where the driver connects, for messages ("192.168.1.10:8055")."""
        host = getattr(self.options, "host", None)
        return str(host) if host else self.name

    def begin_stats(self) -> None:
        with self._stats_lock:
            self._stats = StreamStats(nominal_period_s=self.nominal_period_s)

    def end_stats(self) -> StreamStats | None:
        with self._stats_lock:
            stats, self._stats = self._stats, None
        return stats

    def _reader_loop(self) -> None:
        while self._running.is_set():
            try:
                sample = self._read_sample(READ_TIMEOUT_S)
                if sample is None:
                    continue
                _check_sample(sample, self.limits.n_joints)
            except Exception as exc:  # the stream is broken: keep the reason, trip any armed move
                if not self._running.is_set():
                    return
                self._stream_error = exc if isinstance(exc, PayloadAgentError) else CommunicationError(
                    f"the sample stream failed: {type(exc).__name__}: {exc}")
                self._trip(f"the sample stream failed: {self._stream_error}")
                return
            self._on_sample(sample)

    def _on_sample(self, sample: Sample) -> None:
        self._latest = sample
        with self._stats_lock:
            if self._stats is not None:
                self._stats.add(sample.t_recv, sample.t_ctrl, self.gap_limit_s)
        with self._sink_lock:
            sink = self._sink
            if sink is not None:
                sink(sample)

    # -- motion and supervision ---------------------------------------------------------------
    def move_joints(self, target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                    timeout_s: float) -> None:
        """One PTP joint move, supervised; returns when the controller reports it finished at the target.

        ``speed_rad_s`` caps the leading joint's speed, ``accel_rad_s2`` its acceleration.
        Raises MotionAbortedError on any abnormal end (stop, fault, timeout, target missed) and
        SupervisionTrip when the stream or the command connection failed (the arm was stopped).
        """
        target = as_joint_vector(target_rad, self.limits.n_joints)
        if not np.all(np.isfinite(target)):
            raise MotionAbortedError(f"move target {target.tolist()} is not finite; nothing was sent")
        for what, v in (("speed", speed_rad_s), ("acceleration", accel_rad_s2), ("timeout", timeout_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise MotionAbortedError(f"move {what} {v!r} is not a positive number; nothing was sent")
        if not self._connected:
            raise CommunicationError(f"the {self.name} driver is not connected")
        if self._stream_error is not None:
            raise CommunicationError(f"the sample stream has failed, refusing to move blind: {self._stream_error}")
        latest = self._latest
        age = None if latest is None else time.monotonic() - latest.t_recv
        if age is None or age > self.gap_limit_s:
            raise CommunicationError(f"no fresh sample from the controller ({self.describe_endpoint()}): "
                                     + ("none yet" if age is None else f"the newest is {1000 * age:.0f} ms old")
                                     + "; refusing to move blind")
        self._trip_report = None
        self._tripped.clear()
        self._target, self._at_target_since, self._last_command_ok = target, None, None
        self._armed_since = time.monotonic()
        self._armed = True
        self._commanded = True
        self._stop_requested.clear()
        try:
            self._move_joints(target, float(speed_rad_s), float(accel_rad_s2), float(timeout_s))
        except (SupervisionTrip, MotionNotFinished, MotionStopped):
            raise
        except CommunicationError as exc:  # the command connection failed mid-move: the arm may still go
            self._trip(f"the command connection failed during the move: {exc}")
            raise self._trip_error() from exc
        except BaseException:
            if self._trip_lock.acquire(timeout=self.supervision.stop_ack_timeout_s + 1.0):
                self._trip_lock.release()  # a trip under way (the watchdog stopping the arm) finishes first
            if self._tripped.is_set():  # the driver's error is a consequence of the trip's stop
                raise self._trip_error() from None
            raise
        finally:
            self._armed = False
        if self._tripped.is_set():
            raise self._trip_error()
        self._commanded = False  # the controller reported our move finished at its target

    @property
    def motion_commanded(self) -> bool:
        """Whether a move this session commanded may still be running (what ``stop()`` would stop)."""
        return self._commanded

    def command_ok(self) -> None:
        """A driver that polls its controller during a move calls this after every good reply.

        From the first call in a move on, the watchdog also trips when no good reply came for
        ``Supervision.max_reply_wait_s`` (a controller that stopped answering, or answers far too late).
        """
        self._last_command_ok = time.monotonic()

    def check_supervision(self) -> None:
        """Raise SupervisionTrip if the watchdog has stopped the arm, MotionStopped if this session's stop()
        did (drivers call this while waiting)."""
        if self._tripped.is_set():
            raise self._trip_error()
        if self._stop_requested.is_set() and self._armed:
            raise MotionStopped("the move was stopped on request by this session")

    @property
    def last_stop_report(self) -> StopReport | None:
        return self._trip_report

    def _trip_error(self) -> SupervisionTrip:
        self._tripped.wait(self.supervision.stop_ack_timeout_s + 1.0)
        report = self._trip_report
        text = report.describe() if report is not None else "the motion supervision tripped"
        error = self._trip_error_class(f"motion stopped by the supervision: {text}")
        error.stop_report = report
        return error

    def _watchdog_loop(self) -> None:
        while self._running.is_set():
            time.sleep(WATCHDOG_TICK_S)
            if not self._armed or self._tripped.is_set():
                continue
            now = time.monotonic()
            latest = self._latest
            last = max(latest.t_recv if latest is not None else 0.0, self._armed_since)
            sup = self.supervision
            if now - last > self.gap_limit_s:
                self._trip(f"the sample stream stalled: no sample for {1000 * (now - last):.0f} ms "
                           f"(limit {1000 * self.gap_limit_s:.0f} ms)", fault_t=last + self.gap_limit_s)
            elif not self._command_alive():
                self._trip("the command connection to the controller was lost")
            elif self._last_command_ok is not None and now - self._last_command_ok > sup.max_reply_wait_s:
                self._trip(f"the controller stopped answering: no reply for {1000 * (now - self._last_command_ok):.0f}"
                           f" ms during the move (limit {1000 * sup.max_reply_wait_s:.0f} ms)",
                           command_channel=False)  # a stop queued behind the unanswered request would wait too
            elif self._standing_at_target(latest, now) > sup.finish_grace_s:
                self._trip(f"the controller did not report the move finished although the arm has stood at the "
                           f"target for {sup.finish_grace_s:.1f} s", error=MotionNotFinished)

    def _standing_at_target(self, latest: Sample | None, now: float) -> float:
        """How long the arm has stood at this move's target (0 while it is elsewhere)."""
        target = self._target
        if latest is None or target is None or len(latest.q) != len(target) \
                or float(np.max(np.abs(np.asarray(latest.q) - target))) > AT_TARGET_RAD:
            self._at_target_since = None
            return 0.0
        if self._at_target_since is None:
            self._at_target_since = now
        return now - self._at_target_since

    def _trip(self, reason: str, fault_t: float | None = None,
              error: type[PayloadAgentError] = SupervisionTrip, command_channel: bool = True) -> None:
        """Stop the arm now; only the first trip of a move acts. Safe from any thread."""
        if not self._armed:
            return
        with self._trip_lock:
            if self._tripped.is_set():
                return
            self._trip_error_class = error
            t_fault = fault_t if fault_t is not None else time.monotonic()
            sent_t: float | None = None
            ack = False
            via = "none"
            attempts = 0
            if command_channel and self._command_alive():
                sent_t, via, attempts = time.monotonic(), "command channel", 1
                try:
                    ack = bool(self._stop_command())
                except Exception:
                    ack = False
            deadline = time.monotonic() + self.supervision.stop_ack_timeout_s
            while not ack and time.monotonic() < deadline:
                attempts += 1
                t = time.monotonic()
                try:
                    ack = bool(self._stop_fresh())
                    if sent_t is None or via == "none":
                        sent_t = t
                    via = "new connection"
                except Exception:
                    ack = False
                if not ack:
                    time.sleep(0.05)
            self._trip_report = StopReport(reason, t_fault, sent_t, ack, via, attempts)
            if ack:
                self._commanded = False
            self._tripped.set()

    def stop(self) -> bool:
        """Halt the motion this session commanded, now. Best effort: never raises.

        Sends nothing when no move of ours may be running (none sent, or the last one finished or was
        stopped with an acknowledgement): the arm may then be moving for someone else, a second session or
        the pendant's program, and that is not ours to stop. Returns whether a stop was sent.
        """
        if not self._commanded:
            return False
        self._stop_requested.set()
        self._last_command_ok = None  # the driver is handling the abort itself: no reply watchdog on its stop
        try:
            if self._connected and self._command_alive() and self._stop_command():
                self._commanded = False
                return True
        except Exception:
            pass
        try:
            if self._connected and self._stop_fresh():
                self._commanded = False
        except Exception:
            pass
        return True

    # -- kinematic cross-check ----------------------------------------------------------------
    def flange_pose(self) -> FlangePose | None:
        """The flange pose the controller reports (TCP offset removed), or None if it has none."""
        return None

    # -- optional capabilities ----------------------------------------------------------------
    OPTIONAL_CAPABILITIES: ClassVar[tuple[str, ...]] = ("read_payload", "write_payload", "read_digital_input",
                                                        "read_trigger")

    def capabilities(self) -> frozenset[str]:
        """The optional capabilities this driver offers with these options, known before connecting, so a
        session that needs one (``--apply``, a watch trigger) is refused before its first move. A driver
        whose options decide (a register map) narrows this; the default is the methods it implements."""
        return frozenset(n for n in self.OPTIONAL_CAPABILITIES if getattr(type(self), n) is not getattr(Driver, n))

    def read_payload(self) -> PayloadSetting:
        raise UnsupportedCapability(f"driver {self.name!r} cannot read the payload setting")

    def write_payload(self, payload: PayloadSetting) -> None:
        raise UnsupportedCapability(f"driver {self.name!r} cannot write the payload setting")

    def read_digital_input(self, index: int) -> bool:
        """State of the controller's general-purpose digital input ``index`` (for `watch`)."""
        raise UnsupportedCapability(f"driver {self.name!r} cannot read digital inputs")

    def read_trigger(self) -> bool:
        """The controller's tool-change trigger register (non-zero: a tool change happened), for `watch`."""
        raise UnsupportedCapability(f"driver {self.name!r} has no trigger register")

    def joint_temperatures_c(self) -> tuple[float, ...] | None:
        """Per-joint temperatures in °C as the controller reports them, or None if it does not."""
        return None


def _check_sample(sample: Sample, n: int) -> None:
    if len(sample.q) != n or len(sample.effort) != n:
        raise CommunicationError(f"a sample has {len(sample.q)} angles and {len(sample.effort)} efforts, expected {n}")
    if not (all(math.isfinite(v) for v in sample.q) and all(math.isfinite(v) for v in sample.effort)):
        raise CommunicationError(f"the controller sent a non-finite value: q={list(sample.q)}, "
                                 f"effort={list(sample.effort)}")


def as_joint_vector(values: Sequence[float], n: int = 6) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"expected {n} joint values, got shape {arr.shape}")
    return arr
