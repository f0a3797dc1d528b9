"""Elite Robots EC series (EC63/EC66/EC612): JSON-RPC on TCP 8055, monitor frames on TCP 8056.

The controller's own protocols, no client library needed (Elite ships none on PyPI
for the EC series; see docs/sources.md, "Elite EC"):

* 8055 "control" port: JSON-RPC 2.0, one request per line ending in "\\n"; the reply's
  ``result`` is a JSON-encoded string that is decoded a second time. Motion and
  settings are only accepted in remote mode.
* 8056 "monitor" port: a big-endian binary frame every 8 ms; its first field
  (u32 MessageSize) gives the frame length (1024 bytes on current firmware).

YAML ``driver`` mapping (every key is validated; ``type`` is the registry name):

    driver:
      type: elite_ec
      host: 192.168.1.200        # required
      rpc_port: 8055
      monitor_port: 8056
      sample_source: monitor     # or "poll": get_joint_pos + getRobotTorques on 8055
      poll_rate_hz: 50           # only for sample_source: poll
      connect_timeout_s: 3.0
      reply_timeout_s: 2.0
      tool_num: 0                # tool whose payload read_payload/write_payload use
      joint_max_speed_deg_s: [150, 150, 190, 260, 260, 260]  # optional: each joint's 100 % speed
      max_joint_accel_rad_s2: 6.0  # what moveByJoint acc/dec = 100 % means
      target_tolerance_deg: 0.1  # final position check after a move

Unit mapping of ``move_joints``:

* ``speed``: moveByJoint's speed is a percentage of each joint's maximum speed; the
  synchronized move's leading joint then runs at that percentage of the fastest speed
  the joint maxima allow along this move (v_cap). So speed % = speed_rad_s / v_cap · 100,
  clamped to [0.01, 100]. Without ``joint_max_speed_deg_s`` every joint's maximum is
  ``max_joint_speed_rad_s`` (from the robot YAML) and this is simply
  speed_rad_s / max_joint_speed_rad_s · 100.
* ``acc``/``dec``: percentages too; acc = dec = accel_rad_s2 / max_joint_accel_rad_s2 · 100,
  rounded, clamped to [1, 100] (the controller treats 0 as "its default", which we never
  want: the plan chose the acceleration).
* ``targetPos``: 8 values in degrees (joints 7 and 8 = 0); Elite's library notes that
  some firmware rejects 6.

``joint_temperatures_c()``: the newest monitor frame's ``joint_temperature`` (6 doubles, °C, offset 607).
None with ``sample_source: poll`` (no 8055 method for joint temperatures was found in the public sources),
before the first frame (it waits up to 0.5 s for one), after the monitor stream failed, for a frame too
short to hold the field, or for all-zero / non-finite values (a firmware that leaves that part unfilled).
"""

from __future__ import annotations

import json
import math
import socket
import struct
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
)

MODE_NAMES = {0: "teach", 1: "play", 2: "remote"}
STATE_NAMES = {0: "stopped", 1: "paused", 2: "emergency stop", 3: "running", 4: "error/alarm", 5: "collision"}
SUBTYPE_MODELS = {3: "EC63", 6: "EC66", 12: "EC612"}

# Monitor frame fields the driver reads: (offset, struct format). Same public layout as
# fakes/elite_ec_monitor.MONITOR_LAYOUT, kept separate on purpose so a layout mistake in
# one shows up as a test failure against the other.
_MON_SIZE = (0, "!I")
_MON_TIMESTAMP = (4, "!Q")
_MON_MACHINE_POS = (13, "!8d")
_MON_TORQUE = (173, "!8d")
_MON_ROBOT_STATE = (237, "!i")
_MON_SERVO_READY = (241, "!i")
_MON_ROBOT_MODE = (281, "!i")
_MON_COLLISION = (365, "!B")
_MON_ESTOP = (462, "!B")
_MON_MIN_SIZE = 463  # everything above lies before this offset
# joint_temperature, 6 doubles in °C: in the 1024-byte frame's tail (after jointacc), which Elite's own library
# does not decode; read only from frames long enough to hold it (docs/sources.md, "Elite EC").
_MON_JOINT_TEMP = (607, "!6d")
_MON_JOINT_TEMP_END = 607 + 48
_FIRST_FRAME_WAIT_S = 0.5  # joint_temperatures_c() right after connect(): wait this long for the first frame
_MON_MAX_SIZE = 1 << 16

_DEFAULTS = {
    "rpc_port": 8055,
    "monitor_port": 8056,
    "sample_source": "monitor",
    "poll_rate_hz": 50.0,
    "connect_timeout_s": 3.0,
    "reply_timeout_s": 2.0,
    "tool_num": 0,
    "max_joint_accel_rad_s2": 6.0,
    "target_tolerance_deg": 0.1,
    "joint_max_speed_deg_s": None,
}

# methods whose result may legitimately be a bare (not JSON-encoded) string on some firmware
_STRING_RESULT_METHODS = {"getSoftVersion"}


class EliteRPCError(CommunicationError):
    """The controller answered a JSON-RPC error object."""

    def __init__(self, method: str, code: int, message: str):
        self.method = method
        self.code = code
        self.rpc_message = message
        super().__init__(f"Elite controller refused {method}: {message} (JSON-RPC error {code})")


class _RpcClient:
    """Line-framed JSON-RPC 2.0 over one TCP connection; one call at a time (lock)."""

    def __init__(self, host: str, port: int, connect_timeout_s: float, reply_timeout_s: float):
        self.host, self.port = host, port
        self.reply_timeout_s = reply_timeout_s
        self._lock = threading.Lock()
        self._next_id = 1
        self._buf = b""
        try:
            self._sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as e:
            raise CommunicationError(
                f"cannot connect to the Elite controller's JSON-RPC port {host}:{port}: {e}. "
                "Check the robot's IP address, the network cable, and that the controller is powered on."
            ) from e
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def close(self) -> None:
        try:
            self._sock.close()
        except OSError:
            pass

    def call(self, method: str, params: Mapping[str, Any] | None = None, timeout_s: float | None = None) -> Any:
        timeout = self.reply_timeout_s if timeout_s is None else timeout_s
        with self._lock:
            req_id = self._next_id
            self._next_id += 1
            line = json.dumps({"jsonrpc": "2.0", "method": method, "params": dict(params or {}), "id": req_id},
                              separators=(",", ":")) + "\n"
            try:
                self._sock.sendall(line.encode("utf-8"))
            except OSError as e:
                raise CommunicationError(f"lost the connection to {self.host}:{self.port} sending {method}: {e}") from e
            deadline = time.monotonic() + timeout
            while True:
                raw = self._read_line(method, deadline)
                try:
                    reply = json.loads(raw.decode("utf-8"))
                    if not isinstance(reply, dict):
                        raise ValueError("not a JSON object")
                except (UnicodeDecodeError, ValueError) as e:
                    raise CommunicationError(
                        f"unparseable reply to {method} from {self.host}:{self.port}: {raw[:200]!r} ({e})") from e
                if reply.get("id") != req_id and reply.get("id") is not None:
                    continue  # a late reply to an earlier request that timed out: skip it
                if "error" in reply:
                    err = reply["error"] if isinstance(reply["error"], dict) else {}
                    raise EliteRPCError(method, int(err.get("code", 0) or 0), str(err.get("message", reply["error"])))
                if "result" not in reply:
                    raise CommunicationError(
                        f"reply to {method} from {self.host}:{self.port} has neither result nor error: {raw[:200]!r}")
                result = reply["result"]
                if not isinstance(result, str):
                    return result  # tolerate a controller that does not double-encode
                try:
                    return json.loads(result)
                except ValueError as e:
                    if method in _STRING_RESULT_METHODS:
                        return result
                    raise CommunicationError(
                        f"unparseable result of {method} from {self.host}:{self.port}: {raw[:200]!r} ({e})") from e

    def _read_line(self, method: str, deadline: float) -> bytes:
        while b"\n" not in self._buf:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise CommunicationError(
                    f"no reply to {method} from {self.host}:{self.port} within {self.reply_timeout_s:g} s")
            self._sock.settimeout(remaining)
            try:
                chunk = self._sock.recv(65536)
            except socket.timeout:
                continue
            except OSError as e:
                raise CommunicationError(f"lost the connection to {self.host}:{self.port} waiting for {method}: {e}") from e
            if not chunk:
                raise CommunicationError(f"the controller {self.host}:{self.port} closed the connection during {method}")
            self._buf += chunk
            if len(self._buf) > (1 << 20):
                raise CommunicationError(f"reply to {method} exceeds 1 MiB without a newline: {self._buf[:200]!r}")
        line, self._buf = self._buf.split(b"\n", 1)
        return line.strip()


class EliteECDriver(Driver):
    name = "elite_ec"
    effort_unit = "percent_rated"

    def __init__(self, options: Mapping[str, Any], *, max_joint_speed_rad_s: float, key_path: str = "driver"):
        super().__init__(options, max_joint_speed_rad_s=max_joint_speed_rad_s, key_path=key_path)
        self._cfg = self._validate(dict(options))
        self.host: str = self._cfg["host"]
        self._rpc: _RpcClient | None = None
        self._mon_sock: socket.socket | None = None
        self._reader: threading.Thread | None = None
        self._sink: SampleSink | None = None
        self._sink_lock = threading.Lock()
        self._stop_evt = threading.Event()
        self._stream_error: BaseException | None = None
        self._latest: dict[str, Any] | None = None
        self._frames = 0
        self._first_frame = threading.Event()

    # -- options ----------------------------------------------------------------------------
    def _validate(self, opts: dict[str, Any]) -> dict[str, Any]:
        kp = self.key_path
        known = set(_DEFAULTS) | {"host", "type"}
        for key in opts:
            if key not in known:
                raise ConfigError(f"{kp}.{key}", f"unknown option for the elite_ec driver; expected one of "
                                                 f"{', '.join(sorted(known - {'type'}))}")
        cfg = dict(_DEFAULTS)
        cfg.update({k: v for k, v in opts.items() if k != "type"})
        host = opts.get("host")
        if not isinstance(host, str) or not host.strip():
            raise ConfigError(f"{kp}.host", "the controller's IP address or host name is required (a string)")
        cfg["host"] = host.strip()
        for key in ("rpc_port", "monitor_port"):
            v = cfg[key]
            if not isinstance(v, int) or isinstance(v, bool) or not (1 <= v <= 65535):
                raise ConfigError(f"{kp}.{key}", f"expected a TCP port number 1..65535, got {v!r}")
        if cfg["sample_source"] not in ("monitor", "poll"):
            raise ConfigError(f"{kp}.sample_source", f'expected "monitor" or "poll", got {cfg["sample_source"]!r}')
        for key, lo, hi in (("poll_rate_hz", 1.0, 500.0), ("connect_timeout_s", 0.05, 120.0),
                            ("reply_timeout_s", 0.05, 120.0), ("max_joint_accel_rad_s2", 0.01, 1000.0),
                            ("target_tolerance_deg", 0.0001, 10.0)):
            v = cfg[key]
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or not (lo <= v <= hi):
                raise ConfigError(f"{kp}.{key}", f"expected a number in [{lo:g}, {hi:g}], got {v!r}")
            cfg[key] = float(v)
        v = cfg["joint_max_speed_deg_s"]
        if v is not None:
            if (not isinstance(v, (list, tuple)) or len(v) != 6
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0
                               for x in v)):
                raise ConfigError(f"{kp}.joint_max_speed_deg_s", f"expected 6 positive numbers (deg/s), got {v!r}")
            cfg["joint_max_speed_deg_s"] = [float(x) for x in v]
        v = cfg["tool_num"]
        if not isinstance(v, int) or isinstance(v, bool) or not (0 <= v <= 7):
            raise ConfigError(f"{kp}.tool_num", f"expected a tool number 0..7, got {v!r}")
        if not (self.max_joint_speed_rad_s > 0 and math.isfinite(self.max_joint_speed_rad_s)):
            raise ConfigError(f"{kp}", "max_joint_speed_rad_s must be a positive number")
        return cfg

    # -- connection -------------------------------------------------------------------------
    def connect(self) -> None:
        if self._rpc is not None:
            return
        self._stop_evt.clear()
        self._stream_error = None
        self._latest = None
        self._first_frame.clear()
        self._rpc = _RpcClient(self.host, self._cfg["rpc_port"], self._cfg["connect_timeout_s"],
                               self._cfg["reply_timeout_s"])
        if self._cfg["sample_source"] == "monitor":
            port = self._cfg["monitor_port"]
            try:
                self._mon_sock = socket.create_connection((self.host, port), timeout=self._cfg["connect_timeout_s"])
            except OSError as e:
                self._rpc.close()
                self._rpc = None
                raise CommunicationError(
                    f"cannot connect to the Elite controller's monitor port {self.host}:{port}: {e}. "
                    'Check the port, or set driver.sample_source: "poll" to sample over the JSON-RPC port.'
                ) from e
            self._reader = threading.Thread(target=self._monitor_loop, name="elite-monitor", daemon=True)
        else:
            self._reader = threading.Thread(target=self._poll_loop, name="elite-poll", daemon=True)
        self._reader.start()

    def close(self) -> None:
        self._stop_evt.set()
        with self._sink_lock:
            self._sink = None
        if self._mon_sock is not None:
            try:
                self._mon_sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            try:
                self._mon_sock.close()
            except OSError:
                pass
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=2.0)
        self._reader = None
        self._mon_sock = None
        if self._rpc is not None:
            self._rpc.close()
            self._rpc = None

    def call(self, method: str, params: Mapping[str, Any] | None = None, timeout_s: float | None = None) -> Any:
        """One JSON-RPC call on 8055; the decoded result."""
        if self._rpc is None:
            raise CommunicationError("the elite_ec driver is not connected (call connect() first)")
        return self._rpc.call(method, params, timeout_s)

    def identify(self) -> ControllerInfo:
        firmware = self.call("getSoftVersion")
        subtype = self.call("getRobotSubtype")
        model = SUBTYPE_MODELS.get(subtype, f"EC subtype {subtype}") if isinstance(subtype, int) else str(subtype)
        return ControllerInfo(vendor="Elite Robots", model=model, firmware=str(firmware))

    def state(self) -> ControllerState:
        mode = self._int("getRobotMode")
        servo = self.call("getServoStatus")
        estop = self._int("get_estop_status")
        rstate = self._int("getRobotState")
        detail = f"mode {MODE_NAMES.get(mode, mode)}, robot state {STATE_NAMES.get(rstate, rstate)}"
        return ControllerState(
            mode=MODE_NAMES.get(mode, f"unknown({mode})"),
            servo_on=bool(servo),
            estop=bool(estop) or rstate == 2,
            protective_stop=rstate in (4, 5),
            moving=rstate == 3,
            detail=detail,
        )

    def _int(self, method: str, params: Mapping[str, Any] | None = None) -> int:
        v = self.call(method, params)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise CommunicationError(f"{method} returned {v!r}, expected an integer")
        return int(v)

    def _require_remote(self, what: str) -> None:
        mode = self._int("getRobotMode")
        if mode != 2:
            raise RobotNotReadyError(
                f"cannot {what}: the Elite controller is in {MODE_NAMES.get(mode, mode)} mode. "
                "Turn the teach pendant's mode key to REMOTE and try again.")

    # -- motion -----------------------------------------------------------------------------
    def _check_ready(self) -> None:
        self._require_remote("move the robot")
        if self._int("get_estop_status"):
            raise RobotNotReadyError("the emergency stop is pressed: release it, clear the alarm on the pendant "
                                     "(or clearAlarm), switch the servos on, then try again.")
        rstate = self._int("getRobotState")
        if rstate in (2, 4, 5):
            raise RobotNotReadyError(f"the robot is in {STATE_NAMES[rstate]} state: clear the alarm on the pendant "
                                     "(or clearAlarm), switch the servos on, then try again.")
        if rstate == 3:
            raise RobotNotReadyError("the robot is already running a motion: wait for it to finish or stop it.")
        if rstate == 1:
            raise RobotNotReadyError("the robot is paused: stop the paused program on the pendant first.")
        if not self.call("getServoStatus"):
            raise RobotNotReadyError("the servos are off: switch them on (pendant, or set_servo_status 1 after "
                                     "clearAlarm and syncMotorStatus), then try again.")

    def move_joints(self, target_rad: Sequence[float], speed_rad_s: float, accel_rad_s2: float,
                    timeout_s: float) -> None:
        target = as_joint_vector(target_rad)
        if not np.all(np.isfinite(target)):
            raise ValueError("target contains a non-finite joint value")
        if not (speed_rad_s > 0 and accel_rad_s2 > 0 and timeout_s > 0):
            raise ValueError("speed, acceleration and timeout must be positive")
        self._check_ready()
        v_cap, a_cap = self._lead_caps(self._joint_pos_rad(), target)
        speed_pct = min(100.0, max(0.01, speed_rad_s / v_cap * 100.0))
        acc_pct = int(min(100, max(1, round(accel_rad_s2 / a_cap * 100.0))))
        target_deg = [float(v) for v in np.degrees(target)] + [0.0, 0.0]
        params = {"targetPos": target_deg, "speed": round(speed_pct, 3), "acc": acc_pct, "dec": acc_pct}
        t_start = time.monotonic()
        try:
            ok = self.call("moveByJoint", params)
        except EliteRPCError as e:
            raise MotionAbortedError(f"the controller refused the joint move: {e.rpc_message} "
                                     f"(JSON-RPC error {e.code})") from e
        if ok is not True:
            self.stop()
            raise MotionAbortedError(f"the controller refused the joint move (moveByJoint returned {ok!r}); "
                                     f"robot state: {self._describe_state()}")
        try:
            self._wait_motion_end(target, t_start, timeout_s)
        except BaseException:  # Ctrl-C, lost connection, abort: the robot must not keep going
            self.stop()
            raise

    def _lead_caps(self, q_from: np.ndarray, q_to: np.ndarray) -> tuple[float, float]:
        """Leading joint's speed and acceleration at 100 % (each joint at its own maximum)."""
        if self._cfg["joint_max_speed_deg_s"] is not None:
            vmax = np.radians(np.asarray(self._cfg["joint_max_speed_deg_s"], float))
        else:
            vmax = np.full(6, self.max_joint_speed_rad_s)
        amax = np.full(6, self._cfg["max_joint_accel_rad_s2"])
        d = np.abs(q_to - q_from)
        if float(d.max()) <= 0.0:
            return float(vmax.min()), float(amax.min())
        scale = d / d.max()
        mask = scale > 1e-12
        return float(np.min(vmax[mask] / scale[mask])), float(np.min(amax[mask] / scale[mask]))

    def _describe_state(self) -> str:
        try:
            return STATE_NAMES.get(self._int("getRobotState"), "unknown")
        except Exception:
            return "unknown"

    def _wait_motion_end(self, target: np.ndarray, t_start: float, timeout_s: float) -> None:
        deadline = t_start + timeout_s
        start_grace_s = min(1.0, timeout_s)  # how long a real controller may take to report "running"
        seen_running = False
        tol = math.radians(self._cfg["target_tolerance_deg"])
        while True:
            now = time.monotonic()
            if now > deadline:
                self.stop()
                raise MotionAbortedError(f"the joint move did not finish within {timeout_s:g} s; the robot was stopped")
            try:
                rstate = self._int("getRobotState")
            except CommunicationError:
                self.stop()
                raise
            if rstate == 3:
                seen_running = True
            elif rstate == 0:
                q = self._joint_pos_rad()
                err = float(np.max(np.abs(q - target)))
                if err <= tol:
                    return
                if seen_running or now - t_start > start_grace_s:
                    raise MotionAbortedError(
                        f"the joint move ended {math.degrees(err):.3f} deg away from the target "
                        f"(tolerance {self._cfg['target_tolerance_deg']:g} deg): it was stopped or cut short")
            else:
                self.stop()
                if rstate == 4:
                    # the controller shows "e-stop" (2) only briefly before "error" (4)
                    try:
                        if self._int("get_estop_status"):
                            rstate = 2
                    except Exception:
                        pass
                why = STATE_NAMES.get(rstate, f"state {rstate}")
                hint = {2: "release the emergency stop, clear the alarm and switch the servos on",
                        5: "check for an obstacle, then clear the collision alarm",
                        4: "read the alarm on the pendant and clear it",
                        1: "the motion was paused from the pendant"}.get(rstate, "")
                raise MotionAbortedError(f"the joint move was aborted: robot state {why}. {hint}".strip())
            time.sleep(0.005)

    def _joint_pos_rad(self) -> np.ndarray:
        v = self.call("get_joint_pos")
        if not isinstance(v, list) or len(v) < 6 or not all(isinstance(x, (int, float)) for x in v[:6]):
            raise CommunicationError(f"get_joint_pos returned {v!r}, expected 6 or 8 angles in degrees")
        return np.radians(np.asarray(v[:6], float))

    def stop(self) -> None:
        rpc = self._rpc
        if rpc is None:
            return
        try:
            rpc.call("stop", timeout_s=min(1.0, self._cfg["reply_timeout_s"]))
        except Exception:
            pass

    # -- sampling ---------------------------------------------------------------------------
    def start_stream(self, sink: SampleSink) -> None:
        if self._rpc is None:
            raise CommunicationError("the elite_ec driver is not connected (call connect() first)")
        if self._stream_error is not None:
            raise CommunicationError(f"the sample stream has failed: {self._stream_error}") from self._stream_error
        with self._sink_lock:
            self._sink = sink

    def stop_stream(self) -> None:
        with self._sink_lock:
            self._sink = None

    @property
    def stream_error(self) -> BaseException | None:
        return self._stream_error

    @property
    def latest_monitor(self) -> dict[str, Any] | None:
        """The newest decoded monitor frame (monitor source only)."""
        return self._latest

    def _deliver(self, sample: Sample) -> None:
        with self._sink_lock:
            sink = self._sink
            if sink is not None:
                sink(sample)

    def _monitor_loop(self) -> None:
        sock = self._mon_sock
        assert sock is not None
        buf = bytearray()
        try:
            sock.settimeout(0.5)
            while not self._stop_evt.is_set():
                try:
                    chunk = sock.recv(65536)
                except socket.timeout:
                    continue
                if not chunk:
                    raise CommunicationError(f"the controller closed the monitor port {self.host}:"
                                             f"{self._cfg['monitor_port']}")
                t_recv = time.monotonic()
                buf += chunk
                while len(buf) >= 4:
                    size = struct.unpack_from("!I", buf, 0)[0]
                    if not (_MON_MIN_SIZE <= size <= _MON_MAX_SIZE):
                        raise CommunicationError(
                            f"monitor port {self.host}:{self._cfg['monitor_port']} sent a frame announcing "
                            f"{size} bytes: this is not an Elite EC monitor stream (or it lost sync)")
                    if len(buf) < size:
                        break
                    frame = bytes(buf[:size])
                    del buf[:size]
                    self._handle_frame(frame, t_recv)
        except OSError as e:
            if not self._stop_evt.is_set():
                self._stream_error = CommunicationError(f"monitor port connection lost: {e}")
        except Exception as e:  # a sink that raised, or a protocol error
            if not self._stop_evt.is_set():
                self._stream_error = e

    def _handle_frame(self, frame: bytes, t_recv: float) -> None:
        def get(field):
            off, fmt = field
            return struct.unpack_from(fmt, frame, off)

        ts_ms = get(_MON_TIMESTAMP)[0]
        pos = get(_MON_MACHINE_POS)
        torque = get(_MON_TORQUE)
        temps = get(_MON_JOINT_TEMP) if len(frame) >= _MON_JOINT_TEMP_END else None
        self._latest = {
            "TimeStamp": ts_ms, "machinePos": pos, "torque": torque,
            "robotState": get(_MON_ROBOT_STATE)[0], "servoReady": get(_MON_SERVO_READY)[0],
            "robotMode": get(_MON_ROBOT_MODE)[0], "collision": get(_MON_COLLISION)[0],
            "emergencyStopState": get(_MON_ESTOP)[0], "joint_temperature": temps,
        }
        self._frames += 1
        self._first_frame.set()
        sample = Sample(t_ctrl=ts_ms / 1000.0, t_recv=t_recv,
                        q=tuple(math.radians(v) for v in pos[:6]), effort=tuple(float(v) for v in torque[:6]))
        self._deliver(sample)

    def _poll_loop(self) -> None:
        period = 1.0 / self._cfg["poll_rate_hz"]
        next_t = time.monotonic()
        try:
            while not self._stop_evt.is_set():
                with self._sink_lock:
                    active = self._sink is not None
                if active:
                    q = self._joint_pos_rad()
                    tq = self.call("getRobotTorques")
                    if not isinstance(tq, list) or len(tq) < 6 or not all(isinstance(x, (int, float)) for x in tq[:6]):
                        raise CommunicationError(f"getRobotTorques returned {tq!r}, expected 6 or 8 numbers")
                    self._deliver(Sample(t_ctrl=None, t_recv=time.monotonic(), q=tuple(float(v) for v in q),
                                         effort=tuple(float(v) for v in tq[:6])))
                next_t += period
                delay = next_t - time.monotonic()
                if delay > 0:
                    self._stop_evt.wait(delay)
                else:
                    next_t = time.monotonic()
        except Exception as e:
            if not self._stop_evt.is_set():
                self._stream_error = e

    # -- joint temperatures -----------------------------------------------------------------
    def joint_temperatures_c(self) -> tuple[float, ...] | None:
        """Joint 1..6 temperatures in °C from the newest 8056 monitor frame (``joint_temperature``).

        None when the driver polls over 8055 (``sample_source: poll``: no JSON-RPC method for joint
        temperatures was found in the public sources), when no frame arrived within 0.5 s of asking,
        when the monitor stream has failed (the last frame is stale), when the frame is too short to
        hold the field, or when it holds no plausible reading (all zero or not finite).
        """
        if self._cfg["sample_source"] != "monitor" or self._rpc is None or self._stream_error is not None:
            return None
        if not self._first_frame.is_set():
            reader = self._reader
            if reader is None or not reader.is_alive():
                return None
            self._first_frame.wait(_FIRST_FRAME_WAIT_S)
        latest = self._latest
        temps = None if latest is None else latest.get("joint_temperature")
        if temps is None:
            return None
        values = tuple(float(v) for v in temps)
        if not all(math.isfinite(v) for v in values) or not any(values):
            return None
        return values

    # -- digital inputs ---------------------------------------------------------------------
    def read_digital_input(self, index: int) -> bool:
        """State of the controller's digital input X<index>: JSON-RPC ``getInput {"addr": index}`` -> 0 / 1.

        Elite's own Python library (``elite/_var.py``, ``IO.get_digital_io``) documents X0..X63;
        see docs/sources.md ("Elite EC"). Used by ``payload-agent watch`` to wait for a trigger.
        """
        if not isinstance(index, int) or isinstance(index, bool) or index < 0:
            raise ValueError(f"digital input index must be a non-negative integer, got {index!r}")
        try:
            v = self.call("getInput", {"addr": index})
        except EliteRPCError as e:
            raise CommunicationError(f"the Elite controller refused to read digital input X{index}: {e.rpc_message} "
                                     f"(JSON-RPC error {e.code}); inputs are X0..X63") from e
        if isinstance(v, bool):
            return v
        if isinstance(v, (int, float)) and v in (0, 1):
            return bool(v)
        raise CommunicationError(f"getInput X{index} returned {v!r}, expected 0 or 1")

    # -- payload ----------------------------------------------------------------------------
    def read_payload(self) -> PayloadSetting:
        n = self._cfg["tool_num"]
        v = self.call("get_tool_payload", {"tool_num": n})
        try:
            m = float(v["m"])
            cog = [float(x) for x in v["tool_cog"]]
            if len(cog) != 3:
                raise ValueError("tool_cog must have 3 values")
        except (TypeError, KeyError, ValueError) as e:
            raise CommunicationError(f"get_tool_payload returned {v!r}, expected {{'m': kg, 'tool_cog': [mm x3]}}") from e
        return PayloadSetting(mass_kg=m, cog_m=(cog[0] / 1000.0, cog[1] / 1000.0, cog[2] / 1000.0), tool_num=n)

    def write_payload(self, payload: PayloadSetting) -> None:
        n = self._cfg["tool_num"] if payload.tool_num is None else int(payload.tool_num)
        self._require_remote("write the payload setting")
        cog_mm = [round(float(c) * 1000.0, 3) for c in payload.cog_m]
        try:
            ok = self.call("cmd_set_payload", {"tool_num": n, "m": round(float(payload.mass_kg), 4), "cog": cog_mm})
        except EliteRPCError as e:
            raise RobotNotReadyError(f"the controller refused the payload setting: {e.rpc_message}") from e
        if ok is not True:
            raise RobotNotReadyError(f"the controller refused the payload setting (cmd_set_payload returned {ok!r})")
