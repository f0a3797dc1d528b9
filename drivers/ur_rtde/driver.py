"""``URRTDEDriver``: Universal Robots CB3 / e-Series through SDU's ur-rtde client library.

Three controller services, all through their documented protocols:

* RTDE (30004) at the controller's rate (500 Hz e-Series, 125 Hz CB3), twice: the sample stream
  (``SAMPLE_FIELDS``) on a connection of the driver's own (``sample_reader``), which reads every package;
  the controller's state (``RECIPE``: modes, safety bits, runtime state, speeds) through
  ``rtde_receive.RTDEReceiveInterface``;
* ur-rtde's control script (uploaded on 30003 by ``rtde_control.RTDEControlInterface``, which
  runs in a worker process: ``control``): moveJ / stopJ / setPayload / getTCPOffset /
  stopScript, the command channel;
* the dashboard server (29999, ``dashboard``): identification, Remote Control, and the stop
  over a new connection when RTDE is gone.

Design notes:

* ``_read_sample``: the next package of the sample connection, in the controller's order. ur_rtde's
  receive interface keeps only the newest package and is polled from Python: on a loaded host that lost
  up to a third of the packages (``samples_missed``, from the controller timestamps, counts any still
  skipped). Values no arm can have (angles beyond ±2 turns, currents beyond 100 A, time running
  backwards) are a broken stream: corrupt RTDE data parses.
* ``effort`` is ``actual_current`` in A (motor current; torque = gain × current); each sample also
  carries the controller's ``target_current`` and ``target_moment``, from which the analysis fits
  the current-to-torque constants when no calibration is stored.
* Every ur-rtde command runs bounded (``COMMAND_TIMEOUT_S``; a stop ``STOP_REPLY_S``): a
  control script that does not answer is a failed command channel, never a hung agent. During
  a move the script is asked ``isSteady`` every ``HEARTBEAT_S``: each answer is a ``command_ok()``
  for the base's reply watchdog, so a script that stops answering (or answers late) mid-move
  stops the arm within a fraction of a second.
* The control script is uploaded by the first command (a move, a payload write, the TCP read
  of the kinematic cross-check), not by ``connect()``: uploading it replaces the program the
  robot runs, and a connection that only reads (``watch``) must not do that. It is uploaded
  before the motion supervision is armed (the watchdog would take the missing command
  channel for a lost one).
* Stops: stopJ over the control interface when it lives (``_stop_command``), otherwise the
  dashboard's ``stop`` on a new connection (``_stop_fresh``); the base class retries and
  reports which one the controller acknowledged.
* ur-rtde's constructors return even when the connection failed; ``isConnected()`` is
  checked after each of them.
"""

from __future__ import annotations

import dataclasses
import math
import socket
import sys
import time
from typing import Any, Callable, Sequence

import numpy as np

from payload_agent.errors import ConfigError

try:  # only this driver needs the wheel
    import rtde_control  # noqa: F401
    import rtde_receive
except ImportError as _exc:
    raise ConfigError(
        "driver.type",
        "the ur_rtde driver needs the ur-rtde package, which ships wheels for CPython 3.11 and 3.12 only; "
        "install it with `pip install 'payload-agent[ur]'` on one of those Python versions "
        f"(import failed: {_exc})",
    ) from _exc

from payload_agent.drivers.base import DONE, RUNNING, Driver, MotionLimits, MoveStatus, Supervision, aborted, refused
from payload_agent.drivers.ur_rtde.capabilities import URCapabilities
from payload_agent.drivers.ur_rtde.control import COMMAND_TIMEOUT_S, ControlChannel
from payload_agent.drivers.ur_rtde.dashboard import dashboard_identify, dashboard_query, dashboard_stop
from payload_agent.drivers.ur_rtde.options import URRTDEOptions
from payload_agent.drivers.ur_rtde.sample_reader import RTDESampleReader
from payload_agent.drivers.ur_rtde.states import (RUNTIME_PLAYING, URStatus, controller_state, runtime_name,
                                                  safety_stop)
from payload_agent.errors import CommunicationError, RobotNotReadyError
from payload_agent.types import ControllerInfo, ControllerState, Sample

RTDE_PORT = 30004
# RTDE output recipe of the receive interface (names and types: UR's RTDE guide; the payload
# fields exist from PolyScope 5.5.1 / 3.11 on and are added only there, payload_inertia from 5.11 / 3.15).
RECIPE = ["timestamp", "actual_q", "actual_qd", "actual_current", "actual_TCP_pose", "robot_mode", "safety_mode",
          "safety_status_bits", "runtime_state", "actual_digital_input_bits", "joint_temperatures", "target_current",
          "target_moment"]
PAYLOAD_FIELDS = ["payload", "payload_cog"]
# the sample stream's recipe (``sample_reader``): names and types from UR's RTDE guide
SAMPLE_FIELDS = [("timestamp", "DOUBLE"), ("actual_q", "VECTOR6D"), ("actual_current", "VECTOR6D"),
                 ("target_current", "VECTOR6D"), ("target_moment", "VECTOR6D")]
POLL_TIMEOUT_S = 0.5  # reading the async progress word during a move (a local read in the worker)
HEARTBEAT_S = 0.05  # during a move the control script is asked (isSteady) this often: does it still answer?
STOP_REPLY_S = 0.25  # stopJ over the command channel; then the dashboard is tried
DASHBOARD_STOP_TIMEOUT_S = 0.5
MAX_ANGLE_RAD = 4 * math.pi  # UR joints turn ±2 turns at most
MAX_CURRENT_A = 100.0


@dataclasses.dataclass
class _URMove:
    """The move under way: the script's operation id before it, and whether a new one has shown."""

    op0: int
    seen_new_op: bool = False
    settle_until: float = 0.0


class URRTDEDriver(URCapabilities, Driver):
    name = "ur_rtde"
    options_class = URRTDEOptions
    simulator = "payload_agent.fakes.ur:FakeURController"
    reports_flange_pose = True  # actual_TCP_pose less the TCP offset (getTCPOffset)
    records_controller_targets = True  # target_current and target_moment in the recipe (``Sample``)
    options: URRTDEOptions
    move_poll_s = 0.002

    def __init__(self, options: URRTDEOptions, limits: MotionLimits, supervision: Supervision | None = None):
        super().__init__(options, limits, supervision)
        self.effort_unit = "A"
        self.host = options.host.strip()
        self.frequency_hz: float = options.frequency_hz or 500.0  # CB3 (125 Hz) is known only at connect
        self.nominal_period_s = 1.0 / self.frequency_hz
        self._recv: Any = None
        self._reader: RTDESampleReader | None = None
        self._control = ControlChannel(self.host, self.frequency_hz, options.upper_range_registers)
        self._info: ControllerInfo | None = None
        self._version: tuple[int, ...] = ()
        self._remote: bool | None = None
        self._has_payload_fields = False
        self._has_inertia_field = False  # RTDE payload_inertia: PolyScope 5.11 / 3.15 (ur-rtde's setupRecipes)
        self._inertia_writable = False  # set_target_payload (5.10, ur-rtde's script tag) and its readback (5.11)
        self._script_dead = False  # the move just ended with ur-rtde's script gone: stop from the dashboard
        self._move = _URMove(0)
        self._last_ts: float | None = None
        self._heartbeat_t = 0.0
        self.samples_delivered = 0
        self.samples_missed = 0

    def describe_endpoint(self) -> str:
        return f"{self.host}:{RTDE_PORT}"

    # -- connection ----------------------------------------------------------------------------
    def _open(self) -> None:
        # ur-rtde connects without a timeout (an unreachable address blocks for minutes): check first
        try:
            socket.create_connection((self.host, RTDE_PORT), timeout=self.options.connect_timeout_s).close()
        except OSError as exc:
            raise CommunicationError(f"cannot reach the UR controller at {self.host}:{RTDE_PORT} (RTDE): {exc}") \
                from exc
        self._identify_dashboard()
        if self.options.frequency_hz is None and not (self._version and self._version[0] >= 5):
            self.frequency_hz = 125.0  # CB3
        self.nominal_period_s = 1.0 / self.frequency_hz
        self._control.frequency_hz = self.frequency_hz
        v = self._version + (0, 0, 0)
        self._has_payload_fields = (v[0] == 3 and v[1] >= 11) or (v[0] == 5 and (v[1], v[2]) >= (5, 1)) or v[0] > 5
        self._has_inertia_field = (v[0] == 3 and v[1] >= 15) or (v[0] == 5 and v[1] >= 11) or v[0] > 5
        self._inertia_writable = (v[0] == 5 and v[1] >= 11) or v[0] > 5
        variables = RECIPE + (PAYLOAD_FIELDS if self._has_payload_fields else []) + \
            (["payload_inertia"] if self._has_inertia_field else [])
        try:
            recv = rtde_receive.RTDEReceiveInterface(self.host, self.frequency_hz, variables, False,
                                                     self.options.upper_range_registers)
        except RuntimeError as exc:
            raise CommunicationError(f"RTDE receive interface to {self.host}:{RTDE_PORT} failed: {exc}") from exc
        if not recv.isConnected():
            raise CommunicationError(f"RTDE receive interface to {self.host}:{RTDE_PORT} did not connect "
                                     "(ur-rtde returned without a connection)")
        reader = RTDESampleReader(self.host, RTDE_PORT, self.frequency_hz, SAMPLE_FIELDS)
        try:
            reader.open(self.options.connect_timeout_s)
        except CommunicationError:
            reader.close()
            self._recv = recv
            del recv
            self._end_receive()
            raise
        self._recv, self._reader = recv, reader
        self._last_ts = None

    def _identify_dashboard(self) -> None:
        ident = dashboard_identify(self.host, self.options.connect_timeout_s)
        self._info, self._version, self._remote = ident.info, ident.version, ident.remote

    def _close(self) -> None:
        self._control.close(STOP_REPLY_S * 4)
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.close()
        self._end_receive()

    def _end_receive(self) -> None:
        """End ur-rtde's receive interface (its RTDE connection paused and closed) once. Never raises.

        ``RTDEReceiveInterface.disconnect()`` ends with a fixed 0.5 s sleep ("wait until everything has
        disconnected"), whatever the controller does, and the interface's destructor calls it again (ur-rtde
        1.6.5, src/rtde_receive_interface.cpp; docs/sources.md): a disconnect() before the last reference
        went paid it twice. So the driver drops its reference, the last one, and the destructor disconnects
        once. Should another reference still hold the interface (a traceback's frame), disconnect() is called
        now all the same, so that the connection never outlives close(); its destructor then waits again when
        that reference goes.
        """
        recv, self._recv = self._recv, None
        if recv is None:
            return
        try:
            if sys.getrefcount(recv) > 2:  # more than this frame's name and getrefcount's own argument
                recv.disconnect()
        except Exception:
            pass
        del recv  # the destructor runs here (RTDE pause, socket closed, the 0.5 s)

    def _receive(self):
        if self._recv is None:
            raise CommunicationError("the ur_rtde driver is not connected; call connect() first")
        if not self._recv.isConnected():
            raise CommunicationError(f"lost the RTDE connection to {self.host}:{RTDE_PORT}")
        return self._recv

    def _ensure_control(self) -> None:
        """ur-rtde's control interface connected and its script running (built or re-uploaded if needed).

        A script started anew counts its async operations from the start again, and until its first
        register write the controller's output registers still hold the last script's progress word.
        Read then as the move's "before" state, that stale word can carry the very operation id the new
        move gets, and the move would never be seen to finish. A command the new script answers comes
        after its first write (the script resets its progress word before it takes commands), so one is
        sent before any move of a new script.
        """
        with self._control.lock:
            if self._control.get(lambda: self._state(refresh_remote=True).reason):
                self._wait_receive_playing()
                self._control.request("isSteady", timeout_s=COMMAND_TIMEOUT_S,
                                      what="isSteady (the new control script answers)")

    def _wait_receive_playing(self) -> None:
        """The receive interface's packages may predate the script start: _move_status reads the
        runtime state from them and would take STOPPED for a dead script."""
        r = self._receive()
        self._wait(lambda: r.getRuntimeState() == RUNTIME_PLAYING, 2.0,
                   "the RTDE receive interface to report the control script running")

    def _command_alive(self) -> bool:
        return self._control.alive()

    # -- identity and state ----------------------------------------------------------------------
    def identify(self) -> ControllerInfo:
        if self._info is None:
            self._identify_dashboard()
        return self._info

    def state(self) -> ControllerState:
        return self._state(refresh_remote=True)

    def _state(self, refresh_remote: bool) -> ControllerState:
        r = self._receive()
        if refresh_remote and self._version[:2] >= (5, 6):
            try:
                reply = dashboard_query(self.host, "is in remote control",
                                        timeout_s=min(self.options.connect_timeout_s, 1.0))[0]
                self._remote = "true" in reply.lower()
            except CommunicationError:
                pass  # keep the last known answer
        moving = bool(np.any(np.abs(np.asarray(r.getActualQd())) > 1e-3))
        st = URStatus.read(r, self.host)
        return controller_state(st.robot_mode, st.safety_mode, st.bits, st.runtime, moving, self._remote)

    # -- sample stream ---------------------------------------------------------------------------
    def _read_sample(self, timeout_s: float) -> Sample | None:
        reader = self._reader
        if reader is None:
            raise CommunicationError("the ur_rtde driver is not connected")
        got = reader.read(timeout_s)
        if got is None:
            return None
        ts, q, cur, i_target, tau_target = got
        t_recv = time.monotonic()
        self._check_plausible(ts, q, cur)
        for name, values in (("target_current", i_target), ("target_moment", tau_target)):
            if len(values) != 6 or not all(math.isfinite(v) for v in values):
                raise CommunicationError(f"the RTDE stream from {self.host} sent {name} {list(values)}, not six "
                                         "finite numbers: the data is corrupt")
        if self._last_ts is not None:
            steps = (ts - self._last_ts) * self.frequency_hz  # inf if the timestamps are absurdly far apart
            gap = int(round(steps)) - 1 if math.isfinite(steps) else 0
            if gap > 0:
                self.samples_missed += gap
        self._last_ts = ts
        self.samples_delivered += 1
        return Sample(t_ctrl=ts, t_recv=t_recv, q=tuple(q), effort=tuple(cur), target_current=tuple(i_target),
                      target_moment=tuple(tau_target))

    def _check_plausible(self, ts: float, q: Sequence[float], cur: Sequence[float]) -> None:
        """Corrupt RTDE packages parse into numbers; numbers no UR arm reports end the stream."""
        bad = None
        if not math.isfinite(ts):
            bad = f"the controller timestamp is {ts}"
        elif self._last_ts is not None and ts < self._last_ts:
            bad = f"the controller timestamp went back from {self._last_ts:.6g} s to {ts:.6g} s"
        elif any(math.isfinite(v) and abs(v) > MAX_ANGLE_RAD for v in q):
            bad = f"joint angles {[round(v, 3) for v in q]} rad are beyond any UR joint's range"
        elif any(math.isfinite(v) and abs(v) > MAX_CURRENT_A for v in cur):
            bad = f"motor currents {[round(v, 3) for v in cur]} A are beyond any UR drive's"
        if bad:
            raise CommunicationError(f"the RTDE stream from {self.host} sent values that cannot be real ({bad}): "
                                     "the data is corrupt")

    # -- motion ----------------------------------------------------------------------------------
    def _prepare_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        state = self._state(refresh_remote=False)
        if not state.motion_allowed:
            raise RobotNotReadyError(f"UR controller {self.host}: {state.reason} ({state.detail})")
        self._ensure_control()  # may start the control interface and upload its script: before arming

    def _start_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> MoveStatus | None:
        self._script_dead = False
        ctl = self._control
        with ctl.lock:
            op0 = ctl.request("progress", timeout_s=COMMAND_TIMEOUT_S)[0]
            self.command_ok()  # from here on the reply watchdog wants the script's answers (moveJ, heartbeats)
            ok = ctl.request("moveJ", target.tolist(), speed_rad_s, accel_rad_s2, True, timeout_s=COMMAND_TIMEOUT_S)
            self.command_ok()
            self._heartbeat_t = time.monotonic()
        self._move = _URMove(op0)
        return None if ok else refused(lambda: f"UR controller {self.host}: the controller refused the move "
                                               f"({self._why_not_running()})")

    def _move_status(self) -> MoveStatus:
        r, mv = self._receive(), self._move
        st = URStatus.read(r, self.host)  # raises for corrupt data: a broken stream, not a safety stop
        stopped = self._safety_stopped(st)
        if stopped is not None:
            return stopped
        op_id, running = self._control.request("progress", timeout_s=POLL_TIMEOUT_S)
        if not r.isConnected() or not self._control.connected:
            raise CommunicationError(f"lost the RTDE connection to {self.host} during the move")
        if time.monotonic() - self._heartbeat_t > HEARTBEAT_S:  # a command the script must answer, not a read
            self._control.request("isSteady", timeout_s=POLL_TIMEOUT_S, what="isSteady (heartbeat)")
            self._heartbeat_t = time.monotonic()
            self.command_ok()
        if st.runtime != RUNTIME_PLAYING:
            self._script_dead = True
            return aborted(lambda: f"UR controller {self.host}: the control script stopped during the move "
                                   f"({self._why_not_running()})")
        mv.seen_new_op = mv.seen_new_op or op_id != mv.op0
        if not mv.seen_new_op or running:
            return RUNNING
        # the receive interface's packages may trail the control interface's by a cycle or two: done once they
        # show the arm at rest (the base then checks that it stands at the target)
        now = time.monotonic()
        mv.settle_until = mv.settle_until or now + 10.0 / self.frequency_hz + 0.05 + self.gap_limit_s
        if float(np.max(np.abs(np.asarray(r.getActualQd())))) < 1e-4:
            # at rest, but the status above was read before the progress request, which a busy host can hold for
            # longer than a safety stop takes to halt the arm (and end the script, hence "not running"): the
            # stop shows in a package read now, not in that one (seen once in CI with the host loaded)
            return self._safety_stopped(URStatus.read(r, self.host)) or DONE
        return aborted("the controller reported the move finished but the arm is still moving") \
            if now > mv.settle_until else RUNNING

    def _safety_stopped(self, st: URStatus) -> MoveStatus | None:
        """The move's end when the status shows a safety stop, else None."""
        fault = safety_stop(st.bits, st.safety_mode)
        if not fault:
            return None
        self._script_dead = True  # the script has ended too: only the dashboard's stop can still go
        return aborted(f"UR controller {self.host} stopped the move: {fault}")

    def _why_not_running(self) -> str:
        try:
            st = self._state(refresh_remote=True)
        except CommunicationError as exc:
            return str(exc)
        return st.reason or f"runtime state {runtime_name(self._recv.getRuntimeState())}; {st.detail}"

    def _stop_command(self) -> bool:
        """stopJ (asynchronous: done once the script took it) over the control interface, if it runs.

        Not when the sample connection or the receive interface has lost its connection: then the link to
        the controller is likely gone, ur-rtde's control interface would try to reconnect (and upload its
        script anew) before sending, and the dashboard's stop (``_stop_fresh``) is the quicker and surer way.
        The sample connection reads the socket itself, so it sees a dropped link first. Nor when the move
        just ended in a safety stop or the script stopped: stopJ cannot go then.
        """
        r, reader = self._recv, self._reader
        if r is None or reader is None or reader.lost or not r.isConnected() or self._script_dead:
            return False
        return self._control.stop(self.options.stop_decel_rad_s2, STOP_REPLY_S)

    def _stop_fresh(self) -> bool:
        """The dashboard's ``stop`` on a new connection: independent of RTDE and of the script's state."""
        return dashboard_stop(self.host, min(self.options.connect_timeout_s, DASHBOARD_STOP_TIMEOUT_S))

    def _wait(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise CommunicationError(f"UR controller {self.host}: timed out waiting for {what}")
            time.sleep(0.005)

