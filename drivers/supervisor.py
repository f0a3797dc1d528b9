"""Supervision of every move a driver sends, and the bookkeeping of what this session commanded.

A watchdog thread sits beside the driver (as the sample stream does). While a move is armed it
trips when the stream stalls for longer than the gap limit, when the stream fails, when the
command connection dies, when a controller that was answering stops answering, or when the arm
has stood at the target and the controller still has not reported the move finished. A trip
stops the arm within a fraction of a second, over the command channel if it still lives and
otherwise over a new connection, retries until the controller acknowledges or
``stop_ack_timeout_s`` has passed, and keeps a ``StopReport`` saying which happened.

``commanded`` is set when a move goes out and cleared when the controller reports it finished or
acknowledges our stop: ``stop()`` acts only while it is set, so a session never stops motion it
did not command (another session's, the pendant's program).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from payload_agent.drivers.settings import Supervision
from payload_agent.errors import MotionNotFinished, MotionStopped, PayloadAgentError, SupervisionTrip
from payload_agent.types import Sample, StopReport

AT_TARGET_RAD = math.radians(0.05)  # "the arm is at the target" for the never-finished check
WATCHDOG_TICK_S = 0.005


@dataclass(frozen=True)
class StopChannels:
    """How the supervisor reaches the controller: the driver's hooks."""

    alive: Callable[[], bool]  # the command channel still works (cheap, no round trip)
    stop_command: Callable[[], bool]  # stop over the command channel; True if acknowledged
    stop_fresh: Callable[[], bool]  # stop over a new connection; True if acknowledged


class Supervisor:
    """The watchdog, the trip and the session's own stop of one driver."""

    def __init__(self, settings: Supervision, channels: StopChannels, latest: Callable[[], Sample | None],
                 gap_limit_s: Callable[[], float], name: str):
        self.settings = settings
        self._channels = channels
        self._latest = latest
        self._gap_limit_s = gap_limit_s
        self._name = name
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self.armed = False
        self._armed_since = 0.0
        self._target: np.ndarray | None = None
        self._at_target_since: float | None = None
        self._last_command_ok: float | None = None
        self._error_class: type[PayloadAgentError] = SupervisionTrip
        self._trip_lock = threading.Lock()
        self._tripped = threading.Event()
        self.report: StopReport | None = None
        self.commanded = False
        self._stop_requested = threading.Event()

    # -- life cycle -----------------------------------------------------------------------------
    def start(self) -> None:
        self._running.set()
        self._thread = threading.Thread(target=self._loop, name=f"{self._name}-watchdog", daemon=True)
        self._thread.start()

    def stop_watching(self) -> None:
        self._running.clear()
        th, self._thread = self._thread, None
        if th is not None and th is not threading.current_thread():
            th.join(timeout=2.0)

    # -- one move -------------------------------------------------------------------------------
    def arm(self, target: np.ndarray) -> None:
        """A move is about to go out: supervise it, and remember that this session commanded it."""
        self.report = None
        self._tripped.clear()
        self._target, self._at_target_since, self._last_command_ok = target, None, None
        self._armed_since = time.monotonic()
        self.armed = True
        self.commanded = True
        self._stop_requested.clear()

    def finished(self) -> None:
        """The controller reported the move finished: nothing of ours runs, the never-finished check ends, and
        so does the reply check (the driver stops polling its controller; the stream checks go on)."""
        self.commanded = False
        self._target = None
        self._last_command_ok = None

    def disarm(self) -> None:
        self.armed = False

    @property
    def tripped(self) -> bool:
        return self._tripped.is_set()

    def command_ok(self) -> None:
        self._last_command_ok = time.monotonic()

    def check(self) -> None:
        """SupervisionTrip if the watchdog stopped the arm, MotionStopped if this session's stop() did."""
        if self._tripped.is_set():
            raise self.error()
        if self._stop_requested.is_set() and self.armed:
            raise MotionStopped("the move was stopped on request by this session")

    def wait_for_trip(self, timeout_s: float) -> None:
        """While armed: wait up to ``timeout_s`` for a trip under way or about to come, and raise it."""
        if self.armed:
            self._tripped.wait(timeout_s)
            self.check()

    def settle_trip(self) -> bool:
        """Let a trip under way (the watchdog stopping the arm) finish; whether the move has tripped."""
        if self._trip_lock.acquire(timeout=self.settings.stop_ack_timeout_s + 1.0):
            self._trip_lock.release()
        return self._tripped.is_set()

    def error(self) -> SupervisionTrip:
        self._tripped.wait(self.settings.stop_ack_timeout_s + 1.0)
        report = self.report
        text = report.describe() if report is not None else "the motion supervision tripped"
        error = self._error_class(f"motion stopped by the supervision: {text}")
        error.stop_report = report
        return error

    # -- the watchdog ---------------------------------------------------------------------------
    def _loop(self) -> None:
        while self._running.is_set():
            time.sleep(WATCHDOG_TICK_S)
            if not self.armed or self._tripped.is_set():
                continue
            now = time.monotonic()
            latest = self._latest()
            last = max(latest.t_recv if latest is not None else 0.0, self._armed_since)
            gap_limit, sup = self._gap_limit_s(), self.settings
            if now - last > gap_limit:
                self.trip(f"the sample stream stalled: no sample for {1000 * (now - last):.0f} ms "
                          f"(limit {1000 * gap_limit:.0f} ms)", fault_t=last + gap_limit)
            elif not self._channels.alive():
                self.trip("the command connection to the controller was lost")
            elif self._last_command_ok is not None and now - self._last_command_ok > sup.max_reply_wait_s:
                self.trip(f"the controller stopped answering: no reply for {1000 * (now - self._last_command_ok):.0f}"
                          f" ms during the move (limit {1000 * sup.max_reply_wait_s:.0f} ms)",
                          command_channel=False)  # a stop queued behind the unanswered request would wait too
            elif self._standing_at_target(latest, now) > sup.finish_grace_s:
                self.trip(f"the controller did not report the move finished although the arm has stood at the "
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

    def trip(self, reason: str, fault_t: float | None = None,
             error: type[PayloadAgentError] = SupervisionTrip, command_channel: bool = True) -> None:
        """Stop the arm now; only the first trip of an armed move acts. Safe from any thread."""
        if not self.armed:
            return
        with self._trip_lock:
            if self._tripped.is_set():
                return
            self._error_class = error
            t_fault = fault_t if fault_t is not None else time.monotonic()
            sent_t: float | None = None
            ack, via, attempts = False, "none", 0
            if command_channel and self._channels.alive():
                sent_t, via, attempts = time.monotonic(), "command channel", 1
                try:
                    ack = bool(self._channels.stop_command())
                except Exception:
                    ack = False
            deadline = time.monotonic() + self.settings.stop_ack_timeout_s
            while not ack and time.monotonic() < deadline:
                attempts += 1
                t = time.monotonic()
                try:
                    ack = bool(self._channels.stop_fresh())
                    if sent_t is None or via == "none":
                        sent_t = t
                    via = "new connection"
                except Exception:
                    ack = False
                if not ack:
                    time.sleep(0.05)
            self.report = StopReport(reason, t_fault, sent_t, ack, via, attempts)
            if ack:
                self.commanded = False
            self._tripped.set()

    # -- the session's own stop -----------------------------------------------------------------
    def stop(self, connected: bool) -> bool:
        """Halt the motion this session commanded; never raises. Whether a stop was sent."""
        if not self.commanded:
            return False
        self._stop_requested.set()
        self._last_command_ok = None  # the move's end is being handled: no reply watchdog on the stop
        try:
            if connected and self._channels.alive() and self._channels.stop_command():
                self.commanded = False
                return True
        except Exception:
            pass
        try:
            if connected and self._channels.stop_fresh():
                self.commanded = False
        except Exception:
            pass
        return True
