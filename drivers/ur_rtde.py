"""Universal Robots CB3 / e-Series through SDU's ur-rtde client library.

Talks to three controller services, all through their documented protocols:

* RTDE (30004) through ``rtde_receive.RTDEReceiveInterface`` with an explicit
  recipe (``RECIPE`` below) at the controller's rate: 500 Hz e-Series, 125 Hz CB3;
* ur-rtde's control script (uploaded on 30003 by ``rtde_control.RTDEControlInterface``)
  for moveJ / stopJ / setPayload / stopScript;
* the dashboard server (29999, plain text lines) for model, firmware, serial number
  and remote-control mode (the Python wheel ships no dashboard client module).

YAML ``driver`` mapping (every key is validated; ``type`` is the registry name)::

    driver:
      type: ur_rtde
      host: 192.168.1.10          # required
      frequency_hz: 500           # optional: default 500 on e-Series, 125 on CB3
      connect_timeout_s: 5.0      # reachability check before ur-rtde's own (blocking) connect
      upper_range_registers: false  # ur-rtde's FLAG_UPPER_RANGE_REGISTERS (registers 24..47)
      target_tolerance_deg: 0.1   # final position check after a move
      stop_decel_rad_s2: 2.0      # stopJ deceleration used by stop() and aborted moves
      poll_interval_s: 0.0002     # sample poll period (must be well below 1/frequency)

Design notes:

* ``move_joints`` sends an *asynchronous* moveJ and polls ur-rtde's async progress
  word, the safety status bits and the runtime state, so a protective stop, an
  e-stop, a dead control script, a timeout or ``stop()`` from another thread end
  the move at once with MotionAbortedError. The final position is then checked.
* Samples: RTDEReceiveInterface keeps only the latest data package, so a thread
  polls ``getTimestamp()`` and reads q and current when it changes (timestamp read
  again afterwards: the three getters then came from one package). At 500 Hz this
  delivers >= 95 % of the packages (see tests/test_ur_driver.py); ``samples_missed``
  counts the gaps seen in the controller timestamps.
* ``effort`` is ``actual_current`` in A (motor current; torque = gain × current).
* The control script is uploaded on the first command (move, payload write), not by
  ``connect()``: uploading it replaces the program the robot runs, and a connection that
  only reads (``payload-agent watch`` polling a digital input) must not do that. Remote
  Control is therefore checked by ur-rtde at the first command (RobotNotReadyError).
* ``read_digital_input(i)``: bit i of RTDE ``actual_digital_input_bits`` (0-7 DI, 8-15 CI,
  16-17 tool inputs) through ``getDigitalInState``.
* ``joint_temperatures_c()``: RTDE ``joint_temperatures`` (°C) through ``getJointTemperatures``.
* ur-rtde's constructors return even when the connection failed; ``isConnected()``
  is checked after each of them.
"""

from __future__ import annotations

import math
import re
import socket
import threading
import time
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.drivers.base import (
    ControllerInfo,
    ControllerState,
    Driver,
    PayloadSetting,
    Sample,
    SampleSink,
    as_joint_vector,
)
from payload_agent.errors import (
    CommunicationError,
    ConfigError,
    MotionAbortedError,
    RobotNotReadyError,
    SafetyError,
    UnsupportedCapability,
)

try:
    import rtde_control
    import rtde_receive
except ImportError as _exc:  # only this driver needs the wheel
    raise ConfigError(
        "driver.type",
        "the ur_rtde driver needs the ur-rtde package, which ships wheels for CPython 3.11 and 3.12 only; "
        "install it with `pip install 'payload-agent[ur]'` on one of those Python versions "
        f"(import failed: {_exc})",
    ) from _exc

RTDE_PORT = 30004
DASHBOARD_PORT = 29999

# RTDE output recipe of the receive interface (names and types: UR's RTDE guide; the
# payload fields exist from PolyScope 5.5.1 / 3.11 on and are added only there).
# joint_temperatures (VECTOR6D, °C) feeds getJointTemperatures() (ur_rtde robot_state.cpp: vector<double>).
RECIPE = ["timestamp", "actual_q", "actual_qd", "actual_current", "target_moment", "robot_mode", "safety_mode",
          "safety_status_bits", "runtime_state", "actual_digital_input_bits", "joint_temperatures"]
PAYLOAD_FIELDS = ["payload", "payload_cog"]

ROBOT_MODE_RUNNING = 7
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
                    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
SAFETY_MODE_NAMES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                     6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                     10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                     13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
RUNTIME_NAMES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED", 5: "RESUMING"}
RUNTIME_PLAYING = 2
# actual_digital_input_bits (UR RTDE guide): bits 0-7 standard DI0-7, 8-15 configurable CI0-7, 16-17 tool TI0-1
DIGITAL_INPUT_NAMES = [f"DI{i}" for i in range(8)] + [f"CI{i}" for i in range(8)] + ["TI0", "TI1"]
# safety_status_bits bit numbers (ur_rtde rtde_control_interface.h enum SafetyStatus)
BIT_PROTECTIVE, BIT_RECOVERY, BIT_SAFEGUARD, BIT_SYS_ESTOP, BIT_ROBOT_ESTOP, BIT_ESTOP = 2, 3, 4, 5, 6, 7
BIT_VIOLATION, BIT_FAULT = 8, 9

_OPTIONS = {"type", "host", "frequency_hz", "connect_timeout_s", "upper_range_registers", "target_tolerance_deg",
            "stop_decel_rad_s2", "poll_interval_s"}


def _safety_fault(bits: int, safety_mode: int | None = None) -> str | None:
    """A sentence naming the safety stop in ``safety_status_bits``, or None."""
    if bits & ((1 << BIT_ESTOP) | (1 << BIT_ROBOT_ESTOP) | (1 << BIT_SYS_ESTOP)):
        return "emergency stop is active"
    if bits & (1 << BIT_PROTECTIVE):
        return "protective stop is active"
    if bits & (1 << BIT_SAFEGUARD):
        return "safeguard stop is active"
    if bits & ((1 << BIT_VIOLATION) | (1 << BIT_FAULT)):
        return f"safety system reports {SAFETY_MODE_NAMES.get(safety_mode or 0, 'a fault')}"
    return None


class _Dashboard:
    """Minimal client of the dashboard server: one request line, one reply line."""

    def __init__(self, host: str, timeout_s: float):
        self.host = host
        self.timeout_s = timeout_s

    def query(self, *commands: str) -> list[str]:
        try:
            with socket.create_connection((self.host, DASHBOARD_PORT), timeout=self.timeout_s) as s:
                f = s.makefile("rwb")
                f.readline()  # greeting
                replies = []
                for cmd in commands:
                    f.write(cmd.encode() + b"\n")
                    f.flush()
                    line = f.readline()
                    if not line:
                        raise CommunicationError(f"dashboard server {self.host}:{DASHBOARD_PORT} closed the connection")
                    replies.append(line.decode(errors="replace").strip())
                return replies
        except OSError as exc:
            raise CommunicationError(f"cannot talk to the dashboard server at {self.host}:{DASHBOARD_PORT}: {exc}") \
                from exc


class URRTDEDriver(Driver):
    name = "ur_rtde"
    effort_unit = "A"

    def __init__(self, options: Mapping[str, Any], *, max_joint_speed_rad_s: float, key_path: str = "driver"):
        super().__init__(options, max_joint_speed_rad_s=max_joint_speed_rad_s, key_path=key_path)
        cfg = self._validate(dict(options))
        self.host: str = cfg["host"]
        self.frequency_hz: float | None = cfg["frequency_hz"]
        self.connect_timeout_s: float = cfg["connect_timeout_s"]
        self.upper_range_registers: bool = cfg["upper_range_registers"]
        self.target_tolerance_rad: float = math.radians(cfg["target_tolerance_deg"])
        self.stop_decel_rad_s2: float = cfg["stop_decel_rad_s2"]
        self.poll_interval_s: float = cfg["poll_interval_s"]

        self._recv = None
        self._ctrl = None
        self._info: ControllerInfo | None = None
        self._version: tuple[int, ...] = ()
        self._remote: bool | None = None
        self._has_payload_fields = False
        self._cmd_lock = threading.Lock()  # one ur-rtde command at a time
        self._abort = threading.Event()
        self._stream_thread: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self._stream_error: BaseException | None = None
        self.samples_delivered = 0
        self.samples_missed = 0

    # -- options ----------------------------------------------------------------------------
    def _validate(self, opts: dict[str, Any]) -> dict[str, Any]:
        kp = self.key_path
        for key in opts:
            if key not in _OPTIONS:
                raise ConfigError(f"{kp}.{key}", "unknown option for the ur_rtde driver; expected one of "
                                  + ", ".join(sorted(_OPTIONS - {"type"})))
        host = opts.get("host")
        if not isinstance(host, str) or not host.strip():
            raise ConfigError(f"{kp}.host", "the controller's IP address or host name is required (a string)")

        def number(key: str, default, lo: float, hi: float, lo_open: bool = True):
            v = opts.get(key, default)
            if v is None:
                return None
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or (v <= lo if lo_open else v < lo) or v > hi:
                raise ConfigError(f"{kp}.{key}", f"expected a number in {'(' if lo_open else '['}{lo:g}, {hi:g}], "
                                  f"got {v!r}")
            return float(v)

        cfg = {
            "host": host.strip(),
            "frequency_hz": number("frequency_hz", None, 0.0, 500.0),
            "connect_timeout_s": number("connect_timeout_s", 5.0, 0.0, 120.0),
            "target_tolerance_deg": number("target_tolerance_deg", 0.1, 0.0, 5.0),
            "stop_decel_rad_s2": number("stop_decel_rad_s2", 2.0, 0.0, 40.0),
            "poll_interval_s": number("poll_interval_s", 0.0002, 0.0, 0.01),
        }
        upper = opts.get("upper_range_registers", False)
        if not isinstance(upper, bool):
            raise ConfigError(f"{kp}.upper_range_registers", f"expected true or false, got {upper!r}")
        cfg["upper_range_registers"] = upper
        if not (math.isfinite(self.max_joint_speed_rad_s) and self.max_joint_speed_rad_s > 0):
            raise ConfigError(kp, "max_joint_speed_rad_s must be a positive number")
        return cfg

    # -- connection ----------------------------------------------------------------------------
    def connect(self) -> None:
        if self._recv is not None:
            return
        # ur-rtde connects without a timeout (an unreachable address blocks for minutes): check first
        try:
            socket.create_connection((self.host, RTDE_PORT), timeout=self.connect_timeout_s).close()
        except OSError as exc:
            raise CommunicationError(f"cannot reach the UR controller at {self.host}:{RTDE_PORT} (RTDE): {exc}") \
                from exc
        self._identify_dashboard()
        freq = self.frequency_hz or (500.0 if self._version[:1] and self._version[0] >= 5 else 125.0)
        self.frequency_hz = freq
        v = self._version + (0, 0, 0)
        self._has_payload_fields = (v[0] == 3 and v[1] >= 11) or (v[0] == 5 and (v[1], v[2]) >= (5, 1)) or v[0] > 5
        variables = RECIPE + (PAYLOAD_FIELDS if self._has_payload_fields else [])
        try:
            recv = rtde_receive.RTDEReceiveInterface(self.host, freq, variables, False, self.upper_range_registers)
        except RuntimeError as exc:
            raise CommunicationError(f"RTDE receive interface to {self.host}:{RTDE_PORT} failed: {exc}") from exc
        if not recv.isConnected():
            raise CommunicationError(f"RTDE receive interface to {self.host}:{RTDE_PORT} did not connect "
                                     "(ur-rtde returned without a connection)")
        self._recv = recv
        # ur-rtde's control script is uploaded on the first command (move, stop, payload), not
        # here: uploading it replaces whatever program the robot runs, which a connection that
        # only reads (`watch` polling a digital input) must never do.

    def _identify_dashboard(self) -> None:
        db = _Dashboard(self.host, self.connect_timeout_s)
        version_line, model = db.query("PolyscopeVersion", "get robot model")
        m = re.search(r"(\d+)\.(\d+)\.(\d+)\.(\d+)", version_line)
        if not m:
            raise CommunicationError(f"unexpected PolyscopeVersion reply from {self.host}: {version_line!r}")
        self._version = tuple(int(x) for x in m.groups())
        serial = ""
        if self._version[0] == 5 and self._version[1] >= 6:
            serial, remote = db.query("get serial number", "is in remote control")
            self._remote = "true" in remote.lower()
            if not serial.isdigit():
                serial = ""
        suffix = "e" if self._version[0] >= 5 and not model.endswith("e") else ""
        self._info = ControllerInfo(vendor="Universal Robots", model=f"{model}{suffix}", firmware=m.group(0),
                                    serial=serial)

    def _control(self):
        """The control interface, created (and the script uploaded) on first use."""
        if self._ctrl is not None and not self._ctrl.isConnected():  # lost: start over
            old, self._ctrl = self._ctrl, None
            try:
                old.disconnect()
            except Exception:
                pass
        if self._ctrl is not None:
            if not self._ctrl.isProgramRunning():
                fault = self.state().fault
                if fault:
                    raise RobotNotReadyError(f"UR controller {self.host}: {fault}")
                if not self._ctrl.reuploadScript():
                    raise CommunicationError(f"UR controller {self.host}: could not re-upload ur-rtde's control script")
                self._wait(lambda: self._ctrl.isProgramRunning(), 5.0, "the control script to start")
                self._wait_receive_playing()
            return self._ctrl
        flags = rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT
        if self.upper_range_registers:
            flags |= rtde_control.RTDEControlInterface.FLAG_UPPER_RANGE_REGISTERS
        try:
            ctrl = rtde_control.RTDEControlInterface(self.host, self.frequency_hz, flags)
        except RuntimeError as exc:
            text = str(exc)
            if "remote control" in text:
                raise RobotNotReadyError(f"UR controller {self.host}: switch the teach pendant to Remote Control "
                                         f"({text})") from exc
            state = self.state()
            if state.fault:
                raise RobotNotReadyError(f"UR controller {self.host}: {state.fault} ({text})") from exc
            raise CommunicationError(f"RTDE control interface to {self.host} failed: {text}") from exc
        if not ctrl.isConnected():
            raise CommunicationError(f"RTDE control interface to {self.host}:{RTDE_PORT} did not connect")
        self._ctrl = ctrl
        self._wait_receive_playing()
        return ctrl

    def _wait_receive_playing(self) -> None:
        """The receive interface's packages may predate the script start: move_joints reads the
        runtime state from them and would take STOPPED for a dead script."""
        r = self._receive()
        self._wait(lambda: r.getRuntimeState() == RUNTIME_PLAYING, 2.0,
                   "the RTDE receive interface to report the control script running")

    def close(self) -> None:
        self._abort.set()
        try:
            self.stop_stream()
        except Exception:
            pass
        ctrl, self._ctrl = self._ctrl, None
        if ctrl is not None:
            try:
                if ctrl.isConnected() and ctrl.isProgramRunning():
                    ctrl.stopScript()
            except Exception:
                pass
            try:
                ctrl.disconnect()
            except Exception:
                pass
        recv, self._recv = self._recv, None
        if recv is not None:
            try:
                recv.disconnect()
            except Exception:
                pass

    def _receive(self):
        if self._recv is None:
            raise CommunicationError("the ur_rtde driver is not connected; call connect() first")
        if not self._recv.isConnected():
            raise CommunicationError(f"lost the RTDE connection to {self.host}:{RTDE_PORT}")
        return self._recv

    def identify(self) -> ControllerInfo:
        if self._info is None:
            self._identify_dashboard()
        return self._info

    def state(self) -> ControllerState:
        r = self._receive()
        robot_mode = r.getRobotMode()
        safety_mode = r.getSafetyMode()
        bits = r.getSafetyStatusBits()
        runtime = r.getRuntimeState()
        qd = np.asarray(r.getActualQd())
        estop = bool(bits & ((1 << BIT_ESTOP) | (1 << BIT_ROBOT_ESTOP) | (1 << BIT_SYS_ESTOP)))
        protective = bool(bits & ((1 << BIT_PROTECTIVE) | (1 << BIT_SAFEGUARD)))
        mode = {True: "remote", False: "local", None: "unknown"}[self._remote]
        detail = (f"robot_mode={ROBOT_MODE_NAMES.get(robot_mode, robot_mode)}, "
                  f"safety_mode={SAFETY_MODE_NAMES.get(safety_mode, safety_mode)}, "
                  f"runtime_state={RUNTIME_NAMES.get(runtime, runtime)}")
        other = _safety_fault(bits & ~((1 << BIT_ESTOP) | (1 << BIT_ROBOT_ESTOP) | (1 << BIT_SYS_ESTOP)
                                       | (1 << BIT_PROTECTIVE) | (1 << BIT_SAFEGUARD)), safety_mode)
        if other:
            detail = f"{other}; {detail}"
        return ControllerState(mode=mode, servo_on=robot_mode == ROBOT_MODE_RUNNING and other is None,
                               estop=estop, protective_stop=protective,
                               moving=bool(np.any(np.abs(qd) > 1e-3)), detail=detail)

    # -- motion --------------------------------------------------------------------------------
    def move_joints(self, target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                    timeout_s: float) -> None:
        target = as_joint_vector(target_rad)
        if not np.all(np.isfinite(target)):
            raise SafetyError(f"move target {target.tolist()} is not finite")
        if not (math.isfinite(speed_rad_s) and 0 < speed_rad_s <= self.max_joint_speed_rad_s + 1e-12):
            raise SafetyError(f"joint speed {speed_rad_s} rad/s outside (0, {self.max_joint_speed_rad_s}] rad/s")
        if not (math.isfinite(accel_rad_s2) and 0 < accel_rad_s2 <= 40.0):
            raise SafetyError(f"joint acceleration {accel_rad_s2} rad/s² outside (0, 40] rad/s² (ur-rtde's limit)")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise MotionAbortedError(f"invalid move timeout {timeout_s!r}")
        state = self.state()
        if state.fault:
            raise RobotNotReadyError(f"UR controller {self.host}: {state.fault} ({state.detail})")
        self._abort.clear()
        r = self._receive()
        with self._cmd_lock:
            ctrl = self._control()  # may upload the control script first (up to a few seconds)
            t_start = time.monotonic()
            op0 = ctrl.getAsyncOperationProgressEx().operationId()
            ok = ctrl.moveJ(target.tolist(), float(speed_rad_s), float(accel_rad_s2), True)
        if not ok:
            self._raise_abort("the controller refused the move")
        seen_new_op = False
        while True:
            if self._abort.is_set():
                self._stop_now()
                raise MotionAbortedError("move stopped on request")
            bits = r.getSafetyStatusBits()
            fault = _safety_fault(bits, r.getSafetyMode())
            if fault:
                self._stop_now()
                raise MotionAbortedError(f"UR controller {self.host}: {fault} during the move")
            if not r.isConnected():
                raise MotionAbortedError(f"lost the RTDE connection to {self.host} during the move")
            runtime = r.getRuntimeState()
            if runtime != RUNTIME_PLAYING:
                self._stop_now()
                raise MotionAbortedError(f"UR controller {self.host}: the control script is no longer running "
                                         f"(runtime state {RUNTIME_NAMES.get(runtime, runtime)}) during the move")
            status = ctrl.getAsyncOperationProgressEx()
            if status.operationId() != op0:
                seen_new_op = True
            if seen_new_op and not status.isAsyncOperationRunning():
                break
            if time.monotonic() - t_start > timeout_s:
                self._stop_now()
                raise MotionAbortedError(f"move did not finish within {timeout_s:.1f} s")
            time.sleep(0.002)
        # The receive interface's packages may trail the control interface's by a cycle or
        # two: wait until they show the arm at rest, then check the position.
        deadline = time.monotonic() + 10.0 / (self.frequency_hz or 125.0) + 0.05
        while True:
            err = float(np.max(np.abs(np.asarray(r.getActualQ()) - target)))
            at_rest = float(np.max(np.abs(np.asarray(r.getActualQd())))) < 1e-4
            if err <= self.target_tolerance_rad and at_rest:
                return
            if time.monotonic() > deadline:
                if err <= self.target_tolerance_rad:
                    raise MotionAbortedError("the controller reported the move finished but the arm is still moving")
                raise MotionAbortedError(f"move ended {math.degrees(err):.3f} deg from its target "
                                         f"(tolerance {math.degrees(self.target_tolerance_rad):.3f} deg)")
            time.sleep(0.002)

    def _raise_abort(self, what: str) -> None:
        st = self.state()
        reason = st.fault or st.detail
        raise MotionAbortedError(f"UR controller {self.host}: {what} ({reason})")

    def _stop_now(self) -> None:
        ctrl = self._ctrl
        if ctrl is None:
            return
        if self._cmd_lock.acquire(timeout=1.0):
            try:
                if ctrl.isConnected() and ctrl.isProgramRunning():
                    ctrl.stopJ(self.stop_decel_rad_s2, False)
            except Exception:
                pass
            finally:
                self._cmd_lock.release()

    def stop(self) -> None:
        self._abort.set()
        try:
            self._stop_now()
        except Exception:
            pass

    # -- sampling ------------------------------------------------------------------------------
    def start_stream(self, sink: SampleSink) -> None:
        r = self._receive()
        if self._stream_thread is not None:
            raise RuntimeError("the sample stream is already running")
        self._stream_stop.clear()
        self._stream_error = None
        self._stream_thread = threading.Thread(target=self._stream_loop, args=(r, sink), daemon=True,
                                               name=f"ur-rtde-samples-{self.host}")
        self._stream_thread.start()

    def stop_stream(self) -> None:
        th, self._stream_thread = self._stream_thread, None
        if th is not None:
            self._stream_stop.set()
            th.join(timeout=2.0)

    @property
    def stream_error(self) -> BaseException | None:
        return self._stream_error

    def _stream_loop(self, r, sink: SampleSink) -> None:
        period = 1.0 / (self.frequency_hz or 125.0)
        poll = self.poll_interval_s
        last = None
        last_check = time.monotonic()
        try:
            while not self._stream_stop.is_set():
                ts = r.getTimestamp()
                if ts == last:
                    now = time.monotonic()
                    if now - last_check > 0.5:
                        last_check = now
                        if not r.isConnected():
                            raise CommunicationError(f"lost the RTDE connection to {self.host}:{RTDE_PORT}")
                    time.sleep(poll)
                    continue
                for _ in range(4):  # the getters are separate calls: make sure they saw one package
                    q = r.getActualQ()
                    cur = r.getActualCurrent()
                    ts2 = r.getTimestamp()
                    if ts2 == ts:
                        break
                    ts = ts2
                t_recv = time.monotonic()
                if last is not None:
                    gap = int(round((ts - last) / period)) - 1
                    if gap > 0:
                        self.samples_missed += gap
                last = ts
                sink(Sample(t_ctrl=ts, t_recv=t_recv, q=tuple(q), effort=tuple(cur)))
                self.samples_delivered += 1
        except RuntimeError as exc:  # ur-rtde's getters throw RuntimeError (std::runtime_error)
            self._stream_error = CommunicationError(f"the UR sample stream from {self.host} ended: {exc}")
        except BaseException as exc:  # the sink's own error (or ours): keep it as it is
            self._stream_error = exc

    # -- digital inputs ------------------------------------------------------------------------
    def read_digital_input(self, index: int) -> bool:
        """State of digital input ``index`` from RTDE ``actual_digital_input_bits``.

        Index = bit number: 0-7 standard inputs DI0-DI7, 8-15 configurable CI0-CI7, 16-17 tool
        inputs TI0-TI1 (UR RTDE guide). Read with ur-rtde's ``getDigitalInState`` from the
        receive interface's latest package; needs no control script and no Remote Control.
        """
        if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(DIGITAL_INPUT_NAMES):
            raise ValueError(f"UR digital input index must be an integer in [0, {len(DIGITAL_INPUT_NAMES) - 1}] "
                             f"(0-7 standard DI0-7, 8-15 configurable CI0-7, 16-17 tool TI0-1), got {index!r}")
        r = self._receive()
        try:
            return bool(r.getDigitalInState(index))
        except RuntimeError as exc:  # the field is missing from the recipe / no package yet
            raise CommunicationError(f"UR controller {self.host}: cannot read digital input "
                                     f"{DIGITAL_INPUT_NAMES[index]} (bit {index} of actual_digital_input_bits): {exc}") \
                from exc

    # -- joint temperatures ----------------------------------------------------------------------
    def joint_temperatures_c(self) -> tuple[float, ...]:
        """Joint temperatures in °C: RTDE ``joint_temperatures`` of the receive interface's latest package.

        Through ur-rtde's ``getJointTemperatures`` (the field is in ``RECIPE``); needs no control
        script and no Remote Control.
        """
        r = self._receive()
        try:
            temps = r.getJointTemperatures()
        except RuntimeError as exc:  # the field is missing from the recipe / no package yet
            raise CommunicationError(f"UR controller {self.host}: cannot read joint_temperatures: {exc}") from exc
        values = tuple(float(v) for v in temps)
        if len(values) != 6:
            raise CommunicationError(f"UR controller {self.host}: joint_temperatures has {len(values)} values, "
                                     "expected 6")
        return values

    # -- payload -------------------------------------------------------------------------------
    def read_payload(self) -> PayloadSetting:
        if not self._has_payload_fields:
            raise UnsupportedCapability(f"UR controller {self.host} (PolyScope {'.'.join(map(str, self._version))}) "
                                        "has no RTDE payload fields (they need 5.5.1 / 3.11 or newer)")
        r = self._receive()
        cog = r.getPayloadCog()
        return PayloadSetting(mass_kg=float(r.getPayload()), cog_m=(float(cog[0]), float(cog[1]), float(cog[2])))

    def write_payload(self, payload: PayloadSetting) -> None:
        mass = float(payload.mass_kg)
        cog = [float(c) for c in payload.cog_m]
        if not (math.isfinite(mass) and mass >= 0 and len(cog) == 3 and all(math.isfinite(c) for c in cog)):
            raise ValueError(f"invalid payload {payload!r}")
        # ur-rtde's control script keeps the current centre of gravity when it is sent
        # [0, 0, 0] (rtde_control.script, set_payload branch for PolyScope >= 5.0): send 1 nm instead.
        sent_cog = cog if any(cog) else [0.0, 0.0, 1e-9]
        state = self.state()
        if state.fault:
            raise RobotNotReadyError(f"UR controller {self.host}: {state.fault}")
        with self._cmd_lock:
            ok = self._control().setPayload(mass, sent_cog)
        if not ok:
            self._raise_abort("set_payload was not executed")
        if self._has_payload_fields:
            def matches() -> bool:
                got = self.read_payload()
                return abs(got.mass_kg - mass) < 1e-6 and all(abs(a - b) < 1e-6 for a, b in zip(got.cog_m, cog))

            self._wait(matches, 2.0, "the controller to report the new payload")

    # -- helpers ---------------------------------------------------------------------------------
    def _wait(self, predicate, timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise CommunicationError(f"UR controller {self.host}: timed out waiting for {what}")
            time.sleep(0.005)
