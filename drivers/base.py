"""The driver contract: the only way payload-agent talks to a controller.

A driver knows one protocol family. It never sees a plan or a least-squares matrix; it
moves, streams samples and reports state. Only the safety gate calls ``move_joints``
(see ``payload_agent.motion.safety``).

The base class owns everything every protocol needs, the way python-can's ``BusABC`` owns the
``recv`` loop and each interface fills ``_recv_internal``:

- the **sample stream** (``stream.SampleStream``): a reader thread calls the driver's
  ``_read_sample`` from ``connect()`` to ``close()``, keeps the newest sample, hands every sample
  to the sink, and keeps per-sweep statistics (``begin_stats`` / ``end_stats``);
- the **supervisor** (``supervisor.Supervisor``): a watchdog that stops the arm when the stream
  stalls or fails, the command connection dies or the controller stops answering, and the
  bookkeeping of the move this session commanded (``motion_commanded``, ``stop()``);
- the **move loop** (``move_joints``): checks the request and the stream, lets the driver prepare
  (``_prepare_move``: the motion-allowed check by default; nothing is sent), arms the supervision,
  activates the controller when needed (``_activate``: after connect and after a move that ended
  abnormally; never from ``connect()``), sends the move (``_start_move``, the one place a move
  command goes out), polls ``_move_status`` until it answers done or aborted or the move's time is
  up, stops the arm on any abnormal end (abort, timeout, Ctrl-C, an exception), and checks that the
  arm stands at the target within ``target_tolerance_rad`` once the controller reports it finished.

A driver fills the hooks (docs/drivers.md): ``_open``/``_close``, ``_read_sample``, ``_start_move``,
``_move_status``, ``_stop_command``/``_stop_fresh``, ``identify``/``state``, optionally ``_prepare_move``
and ``_activate``; its options are a typed dataclass (``options_class``), so ``plan`` checks them offline.
"""

from __future__ import annotations

import abc
import math
import time
from typing import Any, ClassVar, Sequence

import numpy as np

from payload_agent.configuration.options import option
from payload_agent.drivers.capabilities import OptionalCapabilities
from payload_agent.drivers.move_request import as_joint_vector, checked_request
from payload_agent.drivers.move_status import DONE, RUNNING, MoveStatus, aborted, refused
from payload_agent.drivers.settings import DriverOptions, MotionLimits, Supervision
from payload_agent.drivers.stream import SampleSink, SampleStream
from payload_agent.drivers.supervisor import StopChannels, Supervisor
from payload_agent.errors import (CommunicationError, ConfigError, MotionAbortedError, MotionNotFinished,
                                  MotionStopped, PayloadAgentError, RobotNotReadyError, SupervisionTrip)
from payload_agent.types import (ControllerInfo, ControllerState, FlangePose, PayloadSetting, Sample, StopReport,
                                 StreamStats)

__all__ = ["Driver", "DriverOptions", "MotionLimits", "SampleSink", "Sample", "ControllerInfo", "ControllerState",
           "PayloadSetting", "FlangePose", "MoveStatus", "RUNNING", "DONE", "aborted", "refused", "as_joint_vector",
           "option"]

MIN_GAP_LIMIT_S = 0.05  # the watchdog never trips on less than this (or 5 sample periods)
SETTLE_PERIODS = 10  # after "finished", the stream may trail the controller by this many samples


class _AbortedMove(Exception):
    """The driver's ``_move_status`` answered aborted: the base stops the arm, then raises its reason."""

    def __init__(self, status: MoveStatus):
        super().__init__("aborted")
        self.status = status


class Driver(OptionalCapabilities, abc.ABC):
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
    # the final position check when the YAML sets no driver.target_tolerance_deg
    default_target_tolerance_deg: ClassVar[float] = 0.1
    move_poll_s: float = 0.005  # how often the move loop asks _move_status

    def __init__(self, options: DriverOptions, limits: MotionLimits, supervision: Supervision | None = None):
        self.options = options
        self.limits = limits
        self.effort_unit: str = ""
        self.nominal_period_s: float = 0.008
        self._connected = False
        self._active = False  # _activate() succeeded and every move since ended normally
        self.stream = SampleStream(self._read_sample, limits.n_joints, self.name, lambda: self.gap_limit_s,
                                   self._stream_failed)
        self.supervisor = Supervisor(supervision or Supervision(),
                                     StopChannels(self._command_alive, self._stop_command, self._stop_fresh),
                                     lambda: self.stream.latest, lambda: self.gap_limit_s, self.name)

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def parse_options(cls, data: Any, key_path: str = "driver", source: str | None = None) -> DriverOptions:
        """The YAML ``driver`` mapping -> this driver's options (ConfigError names the key)."""
        return cls.options_class.parse(data, key_path, source)

    def check_effort_unit(self, yaml_unit: str, key_path: str = "effort.unit") -> None:
        if yaml_unit != self.effort_unit:
            raise ConfigError(key_path, f"the {self.name} driver reports effort in {self.effort_unit!r} with these "
                                        f"driver options, but the YAML says {yaml_unit!r}; set effort.unit to "
                                        f"{self.effort_unit!r} (and its gains to N·m per {self.effort_unit})")

    @property
    def supervision(self) -> Supervision:
        return self.supervisor.settings

    @property
    def gap_limit_s(self) -> float:
        if self.supervision.max_stream_gap_s is not None:
            return self.supervision.max_stream_gap_s
        return max(5 * self.nominal_period_s, MIN_GAP_LIMIT_S)

    @property
    def target_tolerance_rad(self) -> float:
        """How close to the target the arm must stand once the controller reports a move finished."""
        deg = getattr(self.options, "target_tolerance_deg", None)
        return math.radians(self.default_target_tolerance_deg if deg is None else deg)

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

    def _prepare_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Everything before the move goes out, with nothing sent that moves the arm; the supervision is not
        armed yet. Raise to refuse the move (RobotNotReadyError, MotionAbortedError "nothing was sent").
        The default refuses when the controller does not allow motion."""
        st = self.state()
        if not st.motion_allowed:
            raise RobotNotReadyError(st.reason)

    def _activate(self) -> None:
        """Make the controller able to take moves (CiA 402 drives to OPERATION ENABLED), moving nothing. Called
        under the armed supervision before the first move after ``connect()`` and after a move that ended
        abnormally; never by ``connect()``: doctor and plan --connect never energise drives. Raise to refuse."""

    @abc.abstractmethod
    def _start_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> MoveStatus | None:
        """Send one PTP move (the supervision is armed). Return refused(reason) when the controller took nothing
        (no stop is sent then); raise MotionAbortedError when it may have (the base stops the arm)."""

    @abc.abstractmethod
    def _move_status(self) -> MoveStatus:
        """One look at the controller: RUNNING, DONE (it reports the move finished) or aborted(reason).
        Called every ``move_poll_s`` until it is not RUNNING; it may raise CommunicationError (a broken
        connection: the supervision stops the arm)."""

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
    @property
    def connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        if self._connected:
            return
        self._open()
        self._active = False
        self._connected = True
        self.stream.start()
        self.supervisor.start()

    def close(self) -> None:
        """Release connections and threads. Never raises."""
        self.stream.stop()
        self.supervisor.stop_watching()
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
        if self.stream.error is not None:
            raise CommunicationError(f"the sample stream has failed: {self.stream.error}") from self.stream.error
        self.stream.set_sink(sink)

    def stop_stream(self) -> None:
        self.stream.set_sink(None)

    @property
    def stream_error(self) -> BaseException | None:
        """The error that ended the sample stream, if it ended on its own."""
        return self.stream.error

    @property
    def latest_sample(self) -> Sample | None:
        return self.stream.latest

    def wait_sample(self, timeout_s: float, after: float | None = None) -> Sample:
        """The newest sample (received after ``after``, monotonic, if given); CommunicationError on none."""
        return self.stream.wait(timeout_s, after, self.describe_endpoint())

    def describe_endpoint(self) -> str:
        """Where the driver connects, for messages ("192.168.1.10:8055")."""
        host = getattr(self.options, "host", None)
        return str(host) if host else self.name

    def begin_stats(self) -> None:
        self.stream.begin_stats(self.nominal_period_s)

    def end_stats(self) -> StreamStats | None:
        return self.stream.end_stats()

    def _stream_failed(self, reason: str) -> None:
        self.supervisor.trip(reason)

    # -- motion -------------------------------------------------------------------------------
    def move_joints(self, target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                    timeout_s: float) -> None:
        """One PTP joint move, supervised; returns when the controller reports it finished at the target.

        ``speed_rad_s`` caps the leading joint's speed, ``accel_rad_s2`` its acceleration.
        Raises SafetyError beyond the robot's speed limit or the options' ``command_limits`` (nothing sent),
        MotionAbortedError on any abnormal end (stop, fault, timeout, target missed) and SupervisionTrip when the
        stream or the command connection failed (the arm was stopped).
        """
        target, speed, accel, timeout = checked_request(target_rad, speed_rad_s, accel_rad_s2, timeout_s, self.limits,
                                                        type(self.options).command_limits)
        if not self._connected:
            raise CommunicationError(f"the {self.name} driver is not connected")
        if self.stream.error is not None:
            raise CommunicationError(f"the sample stream has failed, refusing to move blind: {self.stream.error}")
        self._prepare_move(target, speed, accel)
        self._check_stream_fresh()
        sup = self.supervisor
        sup.arm(target)
        active, self._active = self._active, False  # again True only when this move ends normally
        try:
            self._run_move(target, speed, accel, timeout, active)
        except (SupervisionTrip, MotionNotFinished, MotionStopped):
            raise
        except CommunicationError as exc:  # the command connection failed mid-move: the arm may still go
            sup.trip(f"the command connection failed during the move: {exc}")
            raise sup.error() from exc
        except BaseException as exc:
            if sup.settle_trip():  # the driver's error is a consequence of the trip's stop
                raise sup.error() from None
            self.stop()  # abort, timeout, Ctrl-C: the arm must not keep going
            if isinstance(exc, _AbortedMove):
                raise MotionAbortedError(exc.status.describe()) from None
            raise
        finally:
            sup.disarm()
        if sup.tripped:
            raise sup.error()
        self._active = True

    def _check_stream_fresh(self) -> None:
        latest = self.stream.latest
        age = None if latest is None else time.monotonic() - latest.t_recv
        if age is None or age > self.gap_limit_s:
            raise CommunicationError(f"no fresh sample from the controller ({self.describe_endpoint()}): "
                                     + ("none yet" if age is None else f"the newest is {1000 * age:.0f} ms old")
                                     + "; refusing to move blind")

    def _run_move(self, target: np.ndarray, speed: float, accel: float, timeout_s: float, active: bool) -> None:
        deadline = time.monotonic() + timeout_s
        if not active:
            self._activate()
        started = self._start_move(target, speed, accel)
        if started is not None and started.state == "refused":
            self._confirm_refusal(started)
        while True:
            self.check_supervision()
            status = self._move_status()
            if status.done:
                break
            if not status.running:
                raise _AbortedMove(status)
            if time.monotonic() > deadline:
                raise _AbortedMove(aborted(f"the move did not finish within {timeout_s:g} s (the controller did not "
                                           "report it finished); the arm was stopped"))
            time.sleep(self.move_poll_s)
        self.supervisor.finished()  # the controller reported our move finished
        self._check_at_target(target, time.monotonic())

    def _confirm_refusal(self, started: MoveStatus) -> None:
        """A refusal counts only from a controller that still talks; one that is the link dropping as the move
        went out (seen with UR's moveJ) may leave our move running: a lost connection, so the arm is stopped."""
        try:  # samples three periods on (past one already on its way), a working command channel
            self.stream.wait(self.gap_limit_s + 0.25, time.monotonic() + 3 * self.nominal_period_s, "")
            alive = self._command_alive()
        except CommunicationError:
            alive = False
        if not alive:
            raise CommunicationError(f"the link failed as the move was sent ({started.describe()})")
        self.supervisor.commanded = False  # nothing of ours runs: no stop may go out
        raise MotionAbortedError(started.describe())

    def _check_at_target(self, target: np.ndarray, t_done: float) -> None:
        """The arm stands within ``target_tolerance_rad`` of the target, on a sample received after the
        controller reported the move finished (the stream may trail it by a few samples)."""
        tol = self.target_tolerance_rad
        settle_until = t_done + SETTLE_PERIODS * self.nominal_period_s + self.gap_limit_s
        after = t_done
        while True:
            sample = self.wait_sample(max(1.0, 20 * self.nominal_period_s), after=after)
            err = np.abs(np.asarray(sample.q) - target)
            if float(err.max()) <= tol:
                return
            if sample.t_recv > settle_until:
                j = int(err.argmax())
                raise MotionAbortedError(f"the controller reported the move finished, but joint {j + 1} is "
                                         f"{math.degrees(err[j]):.3f}° from the target (tolerance "
                                         f"{math.degrees(tol):g}°)")
            self.check_supervision()
            after = sample.t_recv

    @property
    def motion_commanded(self) -> bool:
        """Whether a move this session commanded may still be running (what ``stop()`` would stop)."""
        return self.supervisor.commanded

    @property
    def supervising(self) -> bool:
        """Whether a move is under way (armed) right now."""
        return self.supervisor.armed

    def command_ok(self) -> None:
        """A driver that polls its controller during a move calls this after every good reply: from the first
        call in a move on, the watchdog also trips when none came for ``Supervision.max_reply_wait_s``."""
        self.supervisor.command_ok()

    def check_supervision(self) -> None:
        """Raise SupervisionTrip if the watchdog has stopped the arm, MotionStopped if this session's stop()
        did (drivers call this while waiting)."""
        self.supervisor.check()

    def trip(self, reason: str, error: type[PayloadAgentError] = SupervisionTrip) -> None:
        """Stop the arm now for ``reason`` (a fault the driver detected during a move); the move then raises
        ``error`` with the stop report. Does nothing while no move is armed."""
        self.supervisor.trip(reason, error=error)

    def wait_for_trip(self, timeout_s: float) -> None:
        """During a move: wait up to ``timeout_s`` for a trip the watchdog may be making, and raise it (a
        controller that reports "stopped" may be reporting the supervision's own stop)."""
        self.supervisor.wait_for_trip(timeout_s)

    @property
    def last_stop_report(self) -> StopReport | None:
        return self.supervisor.report

    def stop(self) -> bool:
        """Halt the motion this session commanded, now. Best effort: never raises.

        Sends nothing when no move of ours may be running (none sent, or the last one finished or was
        stopped with an acknowledgement): the arm may then be moving for someone else, a second session or
        the pendant's program, and that is not ours to stop. Returns whether a stop was sent.
        """
        return self.supervisor.stop(self._connected)
