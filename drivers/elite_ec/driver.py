"""Elite Robots EC series (EC63/EC66/EC612): JSON-RPC on TCP 8055, monitor frames on TCP 8056.

The controller's own protocols, no client library needed (Elite ships none on PyPI for the
EC series; see docs/sources.md, "Elite EC"):

* 8055 "control" port: JSON-RPC 2.0, one request per line (``rpc``). Motion and settings are
  only accepted in remote mode.
* 8056 "monitor" port: a big-endian binary frame every 8 ms (``monitor``).

The base class (drivers/base.py) runs the sample stream and supervises every move; this
module fills its hooks. Options: ``EliteECOptions`` (``options``).

Unit mapping of ``move_joints``:

* ``speed``: moveByJoint's speed is a percentage of each joint's maximum speed; the
  synchronized move's leading joint then runs at that percentage of the fastest speed the
  joint maxima allow along this move (``model.profile.lead_joint_caps``). So speed % =
  speed_rad_s / cap · 100, clamped to [0.01, 100]. Without ``joint_max_speed_deg_s`` every
  joint's maximum is the robot YAML's ``max_joint_speed``.
* ``acc``/``dec``: percentages too, of the robot's max joint acceleration, rounded, clamped to [1, 100]
  (the controller treats 0 as "its default", which we never want: the plan chose it).
* ``targetPos``: 8 values in degrees (joints 7 and 8 = 0); Elite's library notes that some
  firmware rejects 6.

``flange_pose()``: the monitor frame's ``machineFlangePose`` (or, polling, JSON-RPC
``get_base_flange_pose``): mm and rad, rotation R = Rz(rz)·Ry(ry)·Rx(rx).

``joint_temperatures_c()``: the newest monitor frame's ``joint_temperature`` (°C, offset 607).
None with ``sample_source: poll`` (no 8055 method for them was found in the public sources),
before the first frame (it waits up to 0.5 s for one), after the stream failed, for a frame
too short to hold the field, or for all-zero / non-finite values.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time
from typing import Any, Mapping

import numpy as np

from payload_agent.drivers.base import DONE, RUNNING, Driver, MotionLimits, MoveStatus, Supervision, aborted, refused
from payload_agent.drivers.elite_ec.monitor import PERIOD_S, MonitorFrame, MonitorStream
from payload_agent.drivers.elite_ec.options import EliteECOptions
from payload_agent.drivers.elite_ec.states import (MODE_NAMES, MODE_REMOTE, STATE_COLLISION, STATE_ERROR,
                                                  STATE_ESTOP, STATE_NAMES, STATE_RUNNING, STATE_STOP, SUBTYPE_MODELS,
                                                  abort_text, refusal)
from payload_agent.drivers.elite_ec.rpc import METHOD_NOT_FOUND, EliteRPCError, RpcClient, stop_over_new_connection
from payload_agent.errors import CommunicationError, ConfigError, MotionAbortedError, RobotNotReadyError
from payload_agent.model.profile import lead_joint_caps, percent_for_lead
from payload_agent.types import ControllerInfo, ControllerState, FlangePose, PayloadSetting, Sample


STOP_TIMEOUT_S = 0.3  # the supervision's stop: how long to wait for the reply
STOP_LINE_WAIT_S = 0.02  # ... and for the command connection to be free
FIRST_FRAME_WAIT_S = 0.5  # joint_temperatures_c() / flange_pose() right after connect(): wait for a frame
START_GRACE_S = 1.0  # how long a real controller may take to report "running" after moveByJoint


@dataclasses.dataclass
class _EliteMove:
    """The move under way: its target, when it was sent, whether the controller has reported it running."""

    target: np.ndarray
    t_start: float
    seen_running: bool = False


class EliteECDriver(Driver):
    name = "elite_ec"
    options_class = EliteECOptions
    simulator = "payload_agent.fakes.elite_ec:FakeEliteController"
    reports_flange_pose = True
    move_poll_s = 0.005  # robot-state polling while a move runs

    def __init__(self, options: EliteECOptions, limits: MotionLimits, supervision: Supervision | None = None):
        super().__init__(options, limits, supervision)
        self.options: EliteECOptions = options
        self.effort_unit = "percent_rated"
        self.nominal_period_s = PERIOD_S if options.sample_source == "monitor" else 1.0 / options.poll_rate_hz
        self._rpc: RpcClient | None = None
        self._poll_rpc: RpcClient | None = None  # sample_source poll: never shares the line with commands
        self._monitor: MonitorStream | None = None
        self._pending: collections.deque[MonitorFrame] = collections.deque()
        self._next_poll_t = 0.0
        self._latest_frame: MonitorFrame | None = None
        self._first_frame = threading.Event()
        self.frames_received = 0
        self._move = _EliteMove(np.zeros(limits.n_joints), 0.0)

    def describe_endpoint(self) -> str:
        return f"{self.options.host}:{self.options.rpc_port}"

    # -- connection ---------------------------------------------------------------------------
    def _open(self) -> None:
        o = self.options
        for key in ("rpc_port", "monitor_port"):
            if getattr(o, key) == 0:
                raise ConfigError(f"driver.{key}", "port 0 only tells a simulated controller to pick a free port; "
                                                   "give the controller's real port (8055 / 8056)")
        self._pending.clear()
        self._latest_frame = None
        self._first_frame.clear()
        self.frames_received = 0
        self._rpc = RpcClient(o.host, o.rpc_port, o.connect_timeout_s, o.reply_timeout_s)
        try:
            if o.sample_source == "monitor":
                self._monitor = MonitorStream(o.host, o.monitor_port, o.connect_timeout_s)
            else:
                self._poll_rpc = RpcClient(o.host, o.rpc_port, o.connect_timeout_s, o.reply_timeout_s,
                                           what="JSON-RPC port (sample polling)")
                self._next_poll_t = time.monotonic()
        except BaseException:
            self._rpc.close()
            self._rpc = None
            raise

    def _close(self) -> None:
        for part in (self._monitor, self._poll_rpc, self._rpc):
            if part is not None:
                part.close()
        self._monitor = self._poll_rpc = self._rpc = None

    def _command_alive(self) -> bool:
        rpc = self._rpc
        return rpc is not None and rpc.alive()

    def call(self, method: str, params: Mapping[str, Any] | None = None, timeout_s: float | None = None) -> Any:
        """One JSON-RPC call on the command connection; the decoded result."""
        if self._rpc is None:
            raise CommunicationError("the elite_ec driver is not connected (call connect() first)")
        return self._rpc.call(method, params, timeout_s)

    # -- sample stream ------------------------------------------------------------------------
    def _read_sample(self, timeout_s: float) -> Sample | None:
        if self.options.sample_source == "poll":
            return self._poll_sample(timeout_s)
        if not self._pending:
            mon = self._monitor
            if mon is None:
                raise CommunicationError("the monitor port is not connected")
            self._pending.extend(mon.read(timeout_s))
            if not self._pending:
                return None
        f = self._pending.popleft()
        self._latest_frame = f
        self.frames_received += 1
        self._first_frame.set()
        return Sample(t_ctrl=f.timestamp_ms / 1000.0, t_recv=f.t_recv,
                      q=tuple(math.radians(v) for v in f.joint_deg[:6]), effort=tuple(float(v) for v in f.torque_pct[:6]))

    def _poll_sample(self, timeout_s: float) -> Sample | None:
        delay = self._next_poll_t - time.monotonic()
        if delay > timeout_s:
            time.sleep(timeout_s)
            return None
        if delay > 0:
            time.sleep(delay)
        period = 1.0 / self.options.poll_rate_hz
        self._next_poll_t = max(self._next_poll_t + period, time.monotonic())
        rpc = self._poll_rpc
        if rpc is None:
            raise CommunicationError("the sample polling connection is not open")
        q = _numbers(rpc.call("get_joint_pos"), "get_joint_pos", "6 or 8 angles in degrees")
        tq = _numbers(rpc.call("getRobotTorques"), "getRobotTorques", "6 or 8 numbers")
        return Sample(t_ctrl=None, t_recv=time.monotonic(), q=tuple(math.radians(v) for v in q),
                      effort=tuple(tq))

    def _fresh_frame(self) -> MonitorFrame | None:
        """The newest monitor frame, waiting briefly for the first one; None if the stream cannot give one."""
        if self.options.sample_source != "monitor" or self._rpc is None or self.stream_error is not None:
            return None
        if not self._first_frame.is_set():
            self._first_frame.wait(FIRST_FRAME_WAIT_S)
        return self._latest_frame

    # -- identity and state -------------------------------------------------------------------
    def identify(self) -> ControllerInfo:
        firmware = self.call("getSoftVersion")
        subtype = self.call("getRobotSubtype")
        model = SUBTYPE_MODELS.get(subtype, f"EC subtype {subtype}") if isinstance(subtype, int) else str(subtype)
        return ControllerInfo(vendor="Elite Robots", model=model, firmware=str(firmware))

    def state(self) -> ControllerState:
        mode = self._int("getRobotMode")
        servo = bool(self.call("getServoStatus"))
        estop = bool(self._int("get_estop_status"))
        rstate = self._int("getRobotState")
        detail = (f"mode {MODE_NAMES.get(mode, mode)}, robot state {STATE_NAMES.get(rstate, rstate)}, "
                  f"servos {'on' if servo else 'off'}")
        estop = estop or rstate == STATE_ESTOP
        reason = refusal(mode, servo, estop, rstate)
        return ControllerState(motion_allowed=not reason, reason=reason, estop=estop,
                               protective_stop=rstate in (STATE_ERROR, STATE_COLLISION),
                               moving=rstate == STATE_RUNNING, detail=detail)

    def _int(self, method: str, params: Mapping[str, Any] | None = None) -> int:
        v = self.call(method, params)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not v.is_integer()):
            raise CommunicationError(f"{method} returned {v!r}, expected an integer")  # NaN and Infinity too
        return int(v)

    def _require_remote(self, what: str) -> None:
        mode = self._int("getRobotMode")
        if mode != MODE_REMOTE:
            raise RobotNotReadyError(
                f"cannot {what}: the Elite controller is in {MODE_NAMES.get(mode, mode)} mode. "
                "Turn the teach pendant's mode key to REMOTE and try again.")

    # -- motion -------------------------------------------------------------------------------
    def _start_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> MoveStatus | None:
        o = self.options
        vmax = (np.radians(np.asarray(o.joint_max_speed_deg_s, float)) if o.joint_max_speed_deg_s is not None
                else np.full(self.limits.n_joints, self.limits.max_joint_speed_rad_s))
        # acc/dec = 100 % is the robot's max joint acceleration (robot.max_joint_accel_deg_s2): one setting
        caps = lead_joint_caps(self._joint_pos_rad(), target, vmax, self.limits.max_joint_accel_rad_s2)
        speed_pct, acc_pct = percent_for_lead(caps, speed_rad_s, accel_rad_s2)
        speed_pct = min(100.0, max(0.01, speed_pct))
        acc_pct = int(min(100, max(1, round(acc_pct))))
        target_deg = [float(v) for v in np.degrees(target)] + [0.0, 0.0]
        params = {"targetPos": target_deg, "speed": round(speed_pct, 3), "acc": acc_pct, "dec": acc_pct}
        self._move = _EliteMove(target, time.monotonic())
        try:
            ok = self.call("moveByJoint", params)
        except EliteRPCError as e:
            return refused(f"the controller refused the joint move: {e.rpc_message} (JSON-RPC error {e.code})")
        if ok is not True:  # an answer no controller should give: it may have taken the move (the base stops it)
            raise MotionAbortedError(f"the controller answered moveByJoint with {ok!r} instead of true, which no "
                                     "Elite controller sends; the arm was stopped in case it took the move")
        return None

    def _move_status(self) -> MoveStatus:
        mv = self._move
        rstate = self._int("getRobotState")
        self.command_ok()  # the controller answers: the watchdog times the next reply from here
        if rstate == STATE_RUNNING:
            mv.seen_running = True
            return RUNNING
        # why, from the controller's state, is read after the stop went out (a round trip must not delay it)
        if rstate != STATE_STOP:
            return aborted(lambda: abort_text(rstate, self.state().estop))
        err = float(np.max(np.abs(self._joint_pos_rad() - mv.target)))
        if err <= self.target_tolerance_rad:
            return DONE
        if not mv.seen_running and time.monotonic() - mv.t_start <= START_GRACE_S:
            return RUNNING  # a real controller takes a moment to report "running" after moveByJoint
        return aborted(lambda: f"the joint move was cut short {math.degrees(err):.3f} deg from the target "
                               f"(tolerance {math.degrees(self.target_tolerance_rad):g} deg): "
                               + (self.state().reason or "it was stopped"))  # the pendant took control back, ...

    def _joint_pos_rad(self) -> np.ndarray:
        return np.radians(np.asarray(_numbers(self.call("get_joint_pos"), "get_joint_pos",
                                              "6 or 8 angles in degrees"), float))

    def _stop_command(self) -> bool:
        rpc = self._rpc
        if rpc is None:
            return False
        # not behind a request still waiting for its reply (a slow controller): the base then goes straight to a new
        # connection, which a controller serves at once, instead of queueing the stop behind the late reply
        return rpc.stop(STOP_TIMEOUT_S, lock_timeout_s=STOP_LINE_WAIT_S)  # False: sent, unacknowledged

    def _stop_fresh(self) -> bool:
        o = self.options
        return stop_over_new_connection(o.host, o.rpc_port, min(o.connect_timeout_s, 0.5),
                                        min(o.reply_timeout_s, 0.5))

    # -- kinematic cross-check ----------------------------------------------------------------
    def flange_pose(self) -> FlangePose | None:
        """The flange pose the controller reports (base frame; tool offset not included)."""
        frame = self._fresh_frame()
        if frame is not None:
            pose = _numbers(list(frame.flange_pose), "the monitor frame's machineFlangePose",
                            "x, y, z (mm), rx, ry, rz (rad) as finite numbers")
        else:
            try:
                pose = self.call("get_base_flange_pose", {"unit_type": 1})
            except EliteRPCError as e:
                if e.code != METHOD_NOT_FOUND:
                    raise
                # older firmware: tool 0's TCP pose (UNVERIFIED that tool 0 has no offset; see docs/sources.md)
                pose = self.call("get_tcp_pose", {"coordinate_num": -1, "tool_num": 0, "unit_type": 1})
            pose = _numbers(pose, "get_base_flange_pose", "x, y, z (mm), rx, ry, rz (rad)", n=6)
        return pose_to_flange(pose)

    # -- joint temperatures, digital inputs, payload ------------------------------------------
    def joint_temperatures_c(self) -> tuple[float, ...] | None:
        """Joint 1..6 temperatures in °C from the newest monitor frame; None when there is no plausible reading."""
        frame = self._fresh_frame()
        temps = None if frame is None else frame.joint_temperature
        if temps is None:
            return None
        values = tuple(float(v) for v in temps)
        if not all(math.isfinite(v) for v in values) or not any(values):
            return None
        return values

    def read_digital_input(self, index: int) -> bool:
        """Digital input X<index>: JSON-RPC ``getInput {"addr": index}`` -> 0 / 1 (X0..X63)."""
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

    def read_payload(self) -> PayloadSetting:
        n = self.options.tool_num
        v = self.call("get_tool_payload", {"tool_num": n})
        try:
            m = float(v["m"])
            if not isinstance(v["tool_cog"], list):
                raise TypeError("tool_cog must be a list")
            cog = [float(x) for x in v["tool_cog"]]
            if len(cog) != 3 or not all(math.isfinite(x) for x in [m, *cog]):
                raise ValueError("expected a finite mass and 3 finite tool_cog values")
        except (TypeError, KeyError, ValueError, OverflowError) as e:
            raise CommunicationError(f"get_tool_payload returned {v!r}, expected {{'m': kg, 'tool_cog': [mm x3]}}") from e
        return PayloadSetting(mass_kg=m, cog_m=(cog[0] / 1000.0, cog[1] / 1000.0, cog[2] / 1000.0), tool_num=n)

    def write_payload(self, payload: PayloadSetting) -> None:
        n = self.options.tool_num if payload.tool_num is None else int(payload.tool_num)
        self._require_remote("write the payload setting")
        cog_mm = [round(float(c) * 1000.0, 3) for c in payload.cog_m]
        try:
            ok = self.call("cmd_set_payload", {"tool_num": n, "m": round(float(payload.mass_kg), 4), "cog": cog_mm})
        except EliteRPCError as e:
            raise RobotNotReadyError(f"the controller refused the payload setting: {e.rpc_message}") from e
        if ok is not True:
            raise RobotNotReadyError(f"the controller refused the payload setting (cmd_set_payload returned {ok!r})")


def _numbers(v: Any, method: str, expected: str, n: int = 6) -> list[float]:
    """The first n values of a numeric list result; CommunicationError for anything else, NaN and
    infinities included (JSON-RPC replies may carry NaN, Infinity and integers too big for a float)."""
    values = None
    if isinstance(v, list) and len(v) >= n and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                   for x in v[:n]):
        try:
            values = [float(x) for x in v[:n]]
        except OverflowError:
            values = None
    if values is None or not all(math.isfinite(x) for x in values):
        raise CommunicationError(f"{method} returned {v!r:.200}, expected {expected}")
    return values


def pose_to_flange(pose: Any) -> FlangePose:
    """Elite pose [x, y, z (mm), rx, ry, rz (rad)] -> FlangePose (m, rotation matrix R = Rz·Ry·Rx)."""
    x, y, z, rx, ry, rz = (float(v) for v in pose)
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    rot = ((cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx),
           (sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx),
           (-sy, cy * sx, cy * cx))
    return FlangePose(position_m=(x / 1000.0, y / 1000.0, z / 1000.0), rotation=rot)
