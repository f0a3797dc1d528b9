"""Simulated Elite Robots EC controller (EC66): JSON-RPC on 8055, monitor frames on 8056.

It serves a ``SimRobot`` on loopback and is strict like the real controller, so a
driver that works against it has a fair chance of working against the robot:

* 8055: line-framed JSON-RPC 2.0, ``result`` always a JSON-encoded string
  (see ``elite_ec_rpc``); motion and settings refused unless the robot is in remote
  mode (``set_mode(2)``), as the real controller only accepts them in remote mode
  (docs.elibot.cn "二次开发端口总结": 8055 commands need remote mode; teach mode only
  answers part of them).
* 8056: a 1024-byte big-endian frame every 8 ms of simulated time
  (see ``elite_ec_monitor``).

Method names, parameter names and units follow Elite's EC SDK socket manual as
used by Elite's own Python library (JunJie-zhang-o/eliterobot, ``elite/_move.py``,
``elite/_baseec.py`` and its ``EliteJson_3_0_2.py``); details in docs/sources.md
("Elite EC"). Points that public sources do not settle are marked UNVERIFIED.

Test-side helpers: ``set_mode(0|1|2)``, ``press_estop()``, ``release_estop()``,
``trigger_collision()``, ``raise_alarm()``, ``set_servo()``, ``set_garbage_reply()``,
``set_digital_input()``, ``set_joint_temperatures()`` / ``joint_temperatures()``.
"""

from __future__ import annotations

import math
import threading
from typing import Any, Sequence

import numpy as np

from payload_agent.fakes.elite_ec_monitor import PERIOD_S, MonitorServer, pack_frame
from payload_agent.fakes.elite_ec_rpc import (
    INVALID_PARAMS,
    METHOD_NOT_FOUND,
    SERVER_ERROR,
    LineJsonRpcServer,
    RpcError,
)
from payload_agent.fakes.sim_robot import SimRefused, SimRobot

# robotState (getRobotState / monitor robotState): 0 stop, 1 pause, 2 e-stop, 3 running,
# 4 error, 5 collision (Elite library enum BaseEC.RobotState).
STATE_STOP, STATE_PAUSE, STATE_ESTOP, STATE_RUNNING, STATE_ERROR, STATE_COLLISION = range(6)
# robotMode (getRobotMode): 0 teach, 1 play (run), 2 remote (BaseEC.RobotMode).
MODE_TEACH, MODE_PLAY, MODE_REMOTE = 0, 1, 2

# getRobotSubtype: 3 EC63, 6 EC66, 12 EC612 (BaseEC.RobotType).
SUBTYPE_EC66 = 6
# getRobotType: Elite's library checks ``robot_type != 62`` for the EC series. UNVERIFIED meaning.
ROBOT_TYPE_EC = 62

# Refusal outside remote mode. UNVERIFIED: the public sources do not show what the real
# controller answers; we answer a JSON-RPC error in the implementation-defined range.
NOT_REMOTE_CODE = SERVER_ERROR
NOT_REMOTE_MESSAGE = "The robot is not in remote mode"

# moveByJoint parameters (SDK manual via Elite's library): targetPos in degrees (8 values;
# Elite's library notes "6 values raise an error" on older firmware; we accept 6 or 8),
# speed = joint speed percentage, range [0.01, 100] here (the manual's jog/setSpeed use
# 0.05..100, path points 1..100); acc/dec = acceleration/deceleration percentage,
# optional, "default 0" -> controller default. Range 0..100 accepted. UNVERIFIED upper bound.
SPEED_MIN_PCT, SPEED_MAX_PCT = 0.01, 100.0
ACC_MIN_PCT, ACC_MAX_PCT = 0.0, 100.0

N_TOOLS = 8  # tool_num 0..7
# Digital inputs X0..X63: getInput {"addr": n} -> 0 or 1 (Elite's library elite/_var.py IO.get_digital_io and its
# docs "变量&IO": "X0~X63", "0低电平,1高电平"). Readable in every mode here (UNVERIFIED on the real controller).
N_DIGITAL_INPUTS = 64

# Joint temperatures (°C) served in the monitor frame's joint_temperature (6 doubles at offset 607). Fake-side
# model, not Elite data: the joints start at these values and warm towards the steady state with a 30-minute
# time constant of simulated time, so values vary slowly over a session. No 8055 method is served for them:
# no public source names one (docs/sources.md, "Elite EC").
DEFAULT_JOINT_TEMPS_C = (31.0, 32.5, 32.0, 34.5, 34.0, 33.5)
DEFAULT_STEADY_JOINT_TEMPS_C = (34.0, 36.5, 35.5, 38.0, 37.0, 36.0)
JOINT_TEMP_TAU_S = 1800.0

# Methods that need remote mode.
_REMOTE_ONLY = {
    "moveByJoint", "cmd_set_payload", "set_servo_status", "syncMotorStatus", "clearAlarm",
    "setAutoRunToolNumber", "resetCollisionState",
}


def lead_joint_caps(q_from: np.ndarray, q_to: np.ndarray, max_speed: np.ndarray,
                    max_accel: np.ndarray) -> tuple[float, float]:
    """Speed and acceleration of the leading joint when every joint runs at its own maximum."""
    d = np.abs(np.asarray(q_to, float) - np.asarray(q_from, float))
    if float(d.max()) <= 0.0:
        return float(np.min(max_speed)), float(np.min(max_accel))
    scale = d / d.max()
    mask = scale > 1e-12
    return float(np.min(max_speed[mask] / scale[mask])), float(np.min(max_accel[mask] / scale[mask]))


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))


def _joint_temps(values: Sequence[float], what: str) -> np.ndarray:
    vals = list(values)
    if len(vals) != 6 or not all(_is_number(v) and -40.0 <= float(v) <= 200.0 for v in vals):
        raise ValueError(f"{what} must be 6 numbers in [-40, 200] °C, got {values!r}")
    return np.asarray(vals, float)


class JointThermal:
    """Per-joint temperatures: a first-order lag towards ``steady`` in simulated time (tau ``JOINT_TEMP_TAU_S``)."""

    def __init__(self, start: Sequence[float], steady: Sequence[float], tau_s: float = JOINT_TEMP_TAU_S):
        self.value = np.asarray(start, float).copy()
        self.steady = np.asarray(steady, float).copy()
        self.tau_s = float(tau_s)
        self._t: float | None = None

    def set(self, values: Sequence[float], steady: Sequence[float] | None = None) -> None:
        self.value = _joint_temps(values, "joint temperatures")
        self.steady = self.value.copy() if steady is None else _joint_temps(steady, "steady joint temperatures")

    def advance(self, t: float) -> None:
        if self._t is not None and t > self._t:
            self.value = self.value + (self.steady - self.value) * (1.0 - math.exp(-(t - self._t) / self.tau_s))
        self._t = t


class FakeEliteController:
    def __init__(self, robot: SimRobot, host: str = "127.0.0.1", rpc_port: int = 8055, monitor_port: int = 8056,
                 rated_torque_nm: Sequence[float] | None = None, gain_error: Sequence[float] | None = None,
                 *, mode: int = MODE_REMOTE, soft_version: str = "3.5.2.sim", subtype: int = SUBTYPE_EC66,
                 max_payload_kg: float = 7.2):
        self.robot = robot
        self.host = host
        spec = robot.spec
        rated = rated_torque_nm if rated_torque_nm is not None else getattr(spec, "rated_torque_nm", (1.0,) * 6)
        self.rated_torque_nm = np.broadcast_to(np.asarray(rated, float), (6,)).copy()
        self.gain_error = np.broadcast_to(np.asarray(1.0 if gain_error is None else gain_error, float), (6,)).copy()
        # moveByJoint "speed"/"acc" are percentages of each joint's own maximum speed and
        # acceleration (as on the pendant); the synchronized PTP move then runs as fast as the
        # most constrained joint allows.
        self.joint_max_speed_rad_s = np.asarray(spec.max_speed_rad_s, float)
        self.joint_max_accel_rad_s2 = np.asarray(spec.max_accel_rad_s2, float)
        self.soft_version = soft_version
        self.subtype = int(subtype)
        self.max_payload_kg = float(max_payload_kg)

        self._lock = threading.RLock()
        self._mode = int(mode)
        self._estop_pressed = False
        self._alarm = False
        self._collision = False
        self._synced = True
        self._servo = bool(robot.snapshot().servo_on)  # commanded servo state (snapshots lag a tick)
        self._auto_tool = 0
        self._reset_t = -1.0  # sim time of the last successful clearAlarm
        self._payloads = [{"m": 0.0, "tool_cog": [0.0, 0.0, 0.0]} for _ in range(N_TOOLS)]
        self._inputs = [0] * N_DIGITAL_INPUTS  # X0..X63, set by tests with set_digital_input()
        self._thermal = JointThermal(DEFAULT_JOINT_TEMPS_C, DEFAULT_STEADY_JOINT_TEMPS_C)
        self._motion: dict | None = None  # {"t0", "dur", "seen"} while robotState is "running"
        self._next_frame_t: float | None = None
        self._garbage: dict[str, str] = {}
        self.frames_sent = 0
        self.requests: list[tuple[str, Any]] = []  # every (method, params) received, for tests

        self._rpc = LineJsonRpcServer(host, rpc_port, self._dispatch, name="elite-rpc",
                                      raw_override=self._raw_override)
        # drop a client only after ~2 s of wall time behind (the sim may run many times faster)
        self._monitor = MonitorServer(host, monitor_port,
                                      max_queue=int(max(250, 2.0 * robot.time_scale / robot.tick_s)))
        self._token: int | None = None
        self._started = False

    # -- lifecycle --------------------------------------------------------------------------
    @property
    def rpc_port(self) -> int:
        return self._rpc.port

    @property
    def monitor_port(self) -> int:
        return self._monitor.port

    def start(self) -> "FakeEliteController":
        if not self._started:
            self._started = True
            self._token = self.robot.subscribe(self._on_tick)
            self._rpc.start()
            self._monitor.start()
        return self

    def close(self) -> None:
        if self._token is not None:
            self.robot.unsubscribe(self._token)
            self._token = None
        self._rpc.close()
        self._monitor.close()

    def __enter__(self) -> "FakeEliteController":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- test-side helpers ------------------------------------------------------------------
    def set_mode(self, mode: int) -> None:
        """Turn the pendant's mode key: 0 teach, 1 play, 2 remote. Leaving remote stops motion."""
        if mode not in (MODE_TEACH, MODE_PLAY, MODE_REMOTE):
            raise ValueError("mode must be 0, 1 or 2")
        with self._lock:
            if mode != MODE_REMOTE and self._mode == MODE_REMOTE:
                self.robot.stop()
            self._mode = mode

    def press_estop(self) -> None:
        with self._lock:
            self._estop_pressed = True
            self._alarm = True
            self.robot.trigger_estop()
            self.robot.set_servo(False)
            self._servo = False

    def release_estop(self) -> None:
        """The button is released; the alarm stays until clearAlarm, servos stay off."""
        with self._lock:
            self._estop_pressed = False

    def trigger_collision(self) -> None:
        with self._lock:
            self._collision = True
            self.robot.trigger_protective_stop()

    def raise_alarm(self) -> None:
        """Any servo/controller alarm: robotState 4 until clearAlarm."""
        with self._lock:
            self._alarm = True
            self.robot.trigger_protective_stop()

    def set_servo(self, on: bool) -> None:
        with self._lock:
            self.robot.set_servo(on)
            self._servo = bool(on)

    def set_garbage_reply(self, method: str, raw_line: str | None) -> None:
        """Answer ``method`` with this raw line (without newline) instead of a proper reply."""
        with self._lock:
            if raw_line is None:
                self._garbage.pop(method, None)
            else:
                self._garbage[method] = raw_line

    def set_digital_input(self, index: int, value: bool | int) -> None:
        """Drive the controller's digital input X<index> (0..63) high (1/True) or low (0/False)."""
        if not isinstance(index, int) or isinstance(index, bool) or not (0 <= index < N_DIGITAL_INPUTS):
            raise ValueError(f"digital input index must be an integer in [0, {N_DIGITAL_INPUTS - 1}], got {index!r}")
        with self._lock:
            self._inputs[index] = 1 if value else 0

    def set_joint_temperatures(self, values: Sequence[float], steady: Sequence[float] | None = None) -> None:
        """Set the joints' temperatures (6 values, °C), shown from the next monitor frame on.

        They then stay put, or, with ``steady``, drift towards it with the fake's 30-minute time constant
        (simulated time).
        """
        with self._lock:
            self._thermal.set(values, steady)

    def joint_temperatures(self) -> tuple[float, ...]:
        """The joints' temperatures (°C) the controller reports now."""
        with self._lock:
            return tuple(float(v) for v in self._thermal.value)

    def payload_setting(self, tool_num: int = 0) -> dict:
        with self._lock:
            p = self._payloads[tool_num]
            return {"m": p["m"], "tool_cog": list(p["tool_cog"])}

    @property
    def mode(self) -> int:
        return self._mode

    def robot_state(self) -> int:
        return self._robot_state(self.robot.snapshot())

    # -- state ------------------------------------------------------------------------------
    def _robot_state(self, s) -> int:
        with self._lock:
            if self._estop_pressed:
                return STATE_ESTOP
            if self._collision:
                return STATE_COLLISION
            # the sim's own safety flags count too (set directly on the SimRobot), except in a
            # snapshot taken before the last clearAlarm (snapshots lag up to one tick)
            if self._alarm or ((s.estop or s.protective_stop) and s.t > self._reset_t):
                return STATE_ERROR
            if self._motion is not None:
                return STATE_RUNNING
            return STATE_STOP

    def _effort_pct(self, torque_nm: np.ndarray) -> np.ndarray:
        # percent of rated torque, with the drive's gain error (current -> torque)
        return np.asarray(torque_nm, float) / self.rated_torque_nm * 100.0 * self.gain_error

    def _on_tick(self, s) -> None:
        with self._lock:
            self._thermal.advance(s.t)
            m = self._motion
            if m is not None:
                if s.moving:
                    m["seen"] = True
                elif m["seen"] or s.t >= m["t0"] + m["dur"] - 1e-9:
                    self._motion = None
            if self._next_frame_t is None:
                self._next_frame_t = (math.floor(s.t / PERIOD_S + 1e-9)) * PERIOD_S
            due = s.t >= self._next_frame_t - 1e-9
            if due:
                # one frame per 8 ms grid point (sample and hold if the tick is coarser)
                while self._next_frame_t <= s.t + 1e-9:
                    self._next_frame_t += PERIOD_S
        if due and self._monitor.has_clients():
            self._monitor.broadcast(self._frame(s))
            self.frames_sent += 1

    def _frame(self, s) -> bytes:
        pct = self._effort_pct(s.torque_nm)
        with self._lock:
            values = {
                "TimeStamp": int(round(s.t * 1000.0)),
                "autorun_cycleMode": 2,
                "machinePos": list(np.degrees(s.q)) + [0.0, 0.0],
                "torque": list(pct) + [0.0, 0.0],
                "robotState": self._robot_state(s),
                "servoReady": 1 if s.servo_on else 0,
                "can_motor_run": 1 if self._synced else 0,
                "robotMode": self._mode,
                "collision": 1 if self._collision else 0,
                "emergencyStopState": 1 if self._estop_pressed else 0,
                "digital_ioInput": sum(1 << i for i, v in enumerate(self._inputs) if v),
                "joint_speed": list(np.degrees(s.qd)) + [0.0, 0.0],
                "jointacc": list(np.degrees(s.qdd)) + [0.0, 0.0],
                "joint_temperature": [float(v) for v in self._thermal.value],
                "jointTorque": list(np.asarray(s.torque_nm, float)),
            }
        return pack_frame(values)

    # -- JSON-RPC ---------------------------------------------------------------------------
    def _raw_override(self, method: str) -> str | None:
        with self._lock:
            return self._garbage.get(method)

    def _dispatch(self, method: str, params: Any) -> Any:
        with self._lock:
            self.requests.append((method, params))
        fn = getattr(self, "_m_" + method, None)
        if fn is None:
            raise RpcError(METHOD_NOT_FOUND, "Method not found")
        if params is None or params == []:
            params = {}
        if not isinstance(params, dict):
            raise RpcError(INVALID_PARAMS, "Invalid params: params must be an object")
        if method in _REMOTE_ONLY and self._mode != MODE_REMOTE:
            raise RpcError(NOT_REMOTE_CODE, NOT_REMOTE_MESSAGE)
        return fn(params)

    # identity
    def _m_getSoftVersion(self, p: dict) -> str:
        return self.soft_version

    def _m_getRobotSubtype(self, p: dict) -> int:
        return self.subtype

    def _m_getRobotType(self, p: dict) -> int:
        return ROBOT_TYPE_EC

    # state
    def _m_getRobotMode(self, p: dict) -> int:
        return self._mode

    def _m_getRobotState(self, p: dict) -> int:
        return self._robot_state(self.robot.snapshot())

    def _m_getServoStatus(self, p: dict) -> bool:
        return self._servo

    def _m_getMotorStatus(self, p: dict) -> bool:
        return self._synced

    def _m_get_estop_status(self, p: dict) -> int:
        return 1 if self._estop_pressed else 0

    def _m_getCollisionState(self, p: dict) -> int:
        return 1 if self._collision else 0

    # servo service
    def _m_set_servo_status(self, p: dict) -> bool:
        status = p.get("status")
        if status not in (0, 1) or isinstance(status, bool):
            raise RpcError(INVALID_PARAMS, "Invalid params: status must be 0 or 1")
        with self._lock:
            if status == 1 and (self._estop_pressed or self._alarm or self._collision or not self._synced):
                return False
        self.set_servo(bool(status))
        return True

    def _m_syncMotorStatus(self, p: dict) -> bool:
        with self._lock:
            self._synced = True
        return True

    def _m_clearAlarm(self, p: dict) -> bool:
        force = p.get("force", 0)
        if force not in (0, 1):
            raise RpcError(INVALID_PARAMS, "Invalid params: force must be 0 or 1")
        with self._lock:
            if self._estop_pressed:
                return False
            self._alarm = False
            self._collision = False
            self.robot.reset_safety()
            self._reset_t = self.robot.now()
        return True

    def _m_resetCollisionState(self, p: dict) -> bool:
        with self._lock:
            self._collision = False
        return True

    # readings
    def _m_get_joint_pos(self, p: dict) -> list[float]:
        return list(np.degrees(self.robot.snapshot().q)) + [0.0, 0.0]

    _m_getRobotPos = _m_get_joint_pos

    def _m_get_joint_speed(self, p: dict) -> list[float]:
        return list(np.degrees(self.robot.snapshot().qd)) + [0.0, 0.0]

    def _m_getRobotTorques(self, p: dict) -> list[float]:
        # 8 values, percent of rated torque (the same quantity as the monitor's "torque")
        return list(self._effort_pct(self.robot.snapshot().torque_nm)) + [0.0, 0.0]

    def _m_get_motor_torque(self, p: dict) -> list[float]:
        # UNVERIFIED: public sources name the method but not its unit; served like getRobotTorques.
        return self._m_getRobotTorques(p)

    # motion
    def _m_moveByJoint(self, p: dict) -> bool:
        target = p.get("targetPos")
        if not isinstance(target, list) or len(target) not in (6, 8) or not all(_is_number(v) for v in target):
            raise RpcError(INVALID_PARAMS, "Invalid params: targetPos must be 6 or 8 numbers (deg)")
        speed = p.get("speed")
        if not _is_number(speed) or not (SPEED_MIN_PCT <= float(speed) <= SPEED_MAX_PCT):
            raise RpcError(INVALID_PARAMS, f"Invalid params: speed must be in [{SPEED_MIN_PCT}, {SPEED_MAX_PCT}]")
        acc_dec = []
        for key in ("acc", "dec"):
            v = p.get(key, 0)
            if not _is_number(v) or not (ACC_MIN_PCT <= float(v) <= ACC_MAX_PCT):
                raise RpcError(INVALID_PARAMS, f"Invalid params: {key} must be in [{ACC_MIN_PCT}, {ACC_MAX_PCT}]")
            acc_dec.append(float(v) if float(v) > 0 else 100.0)  # 0 / absent: controller default
        for key in ("cond_type", "cond_num", "cond_value"):
            if key in p and not isinstance(p[key], int):
                raise RpcError(INVALID_PARAMS, f"Invalid params: {key} must be an integer")
        target_rad = np.radians(np.asarray(target[:6], float))
        v_cap, a_cap = lead_joint_caps(self.robot.snapshot().q, target_rad, self.joint_max_speed_rad_s,
                                       self.joint_max_accel_rad_s2)
        v = float(speed) / 100.0 * v_cap
        a = min(acc_dec) / 100.0 * a_cap  # the sim has one acceleration for both ramps
        with self._lock:
            if self._robot_state(self.robot.snapshot()) != STATE_STOP:
                return False  # alarm, e-stop, collision or already running: refused
            try:
                t0 = self.robot.now()
                dur = self.robot.move_joints(target_rad, v, a)
            except SimRefused:
                return False
            self._motion = {"t0": t0, "dur": dur, "seen": False}
        return True

    def _m_stop(self, p: dict) -> bool:
        self.robot.stop()
        return True

    # payload
    def _tool_num(self, p: dict) -> int:
        n = p.get("tool_num")
        if not isinstance(n, int) or isinstance(n, bool) or not (0 <= n < N_TOOLS):
            raise RpcError(INVALID_PARAMS, "Invalid params: tool_num must be an integer in [0, 7]")
        return n

    def _m_cmd_set_payload(self, p: dict) -> bool:
        # {"tool_num": 0..7, "m": kg, "cog": [x, y, z] mm}; "point" is the pre-2.19.2 name of "cog"
        n = self._tool_num(p)
        m = p.get("m")
        if not _is_number(m) or not (0.0 <= float(m) <= self.max_payload_kg):
            raise RpcError(INVALID_PARAMS, f"Invalid params: m must be in [0, {self.max_payload_kg}] kg")
        cog = p.get("cog", p.get("point"))
        if not isinstance(cog, list) or len(cog) != 3 or not all(_is_number(v) for v in cog):
            raise RpcError(INVALID_PARAMS, "Invalid params: cog must be [x, y, z] in mm")
        if any(abs(float(v)) > 5000.0 for v in cog):
            raise RpcError(INVALID_PARAMS, "Invalid params: cog components must be in [-5000, 5000] mm")
        with self._lock:
            self._payloads[n] = {"m": float(m), "tool_cog": [float(v) for v in cog]}
        return True

    def _m_get_tool_payload(self, p: dict) -> dict:
        n = self._tool_num(p)
        return self.payload_setting(n)

    def _m_getPayload(self, p: dict) -> float:
        return self.payload_setting(self._tool_num(p))["m"]

    def _m_getCentreMass(self, p: dict) -> list[float]:
        return self.payload_setting(self._tool_num(p))["tool_cog"]

    def _m_getAutoRunToolNumber(self, p: dict) -> int:
        return self._auto_tool

    def _m_setAutoRunToolNumber(self, p: dict) -> bool:
        n = self._tool_num(p)
        with self._lock:
            self._auto_tool = n
        return True

    # digital IO
    def _m_getInput(self, p: dict) -> int:
        n = p.get("addr")
        if not isinstance(n, int) or isinstance(n, bool) or not (0 <= n < N_DIGITAL_INPUTS):
            raise RpcError(INVALID_PARAMS, f"Invalid params: addr must be an integer in [0, {N_DIGITAL_INPUTS - 1}]")
        with self._lock:
            return self._inputs[n]
