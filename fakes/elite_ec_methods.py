"""The JSON-RPC methods (port 8055) of the simulated Elite EC controller.

A mixin of ``FakeEliteController`` (fakes/elite_ec.py): one ``_m_<method>`` per Elite method,
taking the request's ``params`` object and returning the value the server JSON-encodes into
``result`` (or raising ``RpcError``). Method names, parameter names and units follow Elite's EC
SDK socket manual as used by Elite's own Python library (JunJie-zhang-o/eliterobot); details and
the points public sources do not settle (marked UNVERIFIED) are in docs/sources.md ("Elite EC").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from payload_agent.fakes.elite_ec_rpc import INVALID_PARAMS, RpcError
from payload_agent.fakes.sim_robot import SimRefused
from payload_agent.model.profile import lead_from_percent, lead_joint_caps

# robotState (getRobotState / monitor robotState): 0 stop, 1 pause, 2 e-stop, 3 running,
# 4 error, 5 collision (Elite library enum BaseEC.RobotState).
STATE_STOP, STATE_PAUSE, STATE_ESTOP, STATE_RUNNING, STATE_ERROR, STATE_COLLISION = range(6)
# robotMode (getRobotMode): 0 teach, 1 play (run), 2 remote (BaseEC.RobotMode).
MODE_TEACH, MODE_PLAY, MODE_REMOTE = 0, 1, 2
# getRobotSubtype: 3 EC63, 6 EC66, 12 EC612 (BaseEC.RobotType).
SUBTYPE_EC66 = 6
# getRobotType: Elite's library checks ``robot_type != 62`` for the EC series. UNVERIFIED meaning.
ROBOT_TYPE_EC = 62

# moveByJoint parameters: targetPos in degrees (8 values; Elite's library notes "6 values raise
# an error" on older firmware; we accept 6 or 8), speed = joint speed percentage, range
# [0.01, 100] here; acc/dec = acceleration/deceleration percentage, optional, "default 0" ->
# controller default. Range 0..100 accepted. UNVERIFIED upper bound.
SPEED_MIN_PCT, SPEED_MAX_PCT = 0.01, 100.0
ACC_MIN_PCT, ACC_MAX_PCT = 0.0, 100.0

N_TOOLS = 8  # tool_num 0..7
# Digital inputs X0..X63: getInput {"addr": n} -> 0 or 1. Readable in every mode here (UNVERIFIED).
N_DIGITAL_INPUTS = 64


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))


def _unit_type(p: dict) -> int:
    """Elite's ``unit_type``: 0 degrees, 1 radians; absent = radians (Elite library, get_tcp_pose)."""
    u = p.get("unit_type", 1)
    if u not in (0, 1) or isinstance(u, bool):
        raise RpcError(INVALID_PARAMS, "Invalid params: unit_type must be 0 (deg) or 1 (rad)")
    return u


def _in_unit(pose: list[float], unit_type: int) -> list[float]:
    return pose[:3] + ([math.degrees(v) for v in pose[3:]] if unit_type == 0 else pose[3:])


class EliteMethods:
    """The ``_m_*`` handlers; the controller provides the state they read and change."""

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

    # Cartesian poses: [x, y, z] mm, [rx, ry, rz] rad (or deg with unit_type 0), R = Rz(rz)·Ry(ry)·Rx(rx).
    # The fake's tools have no TCP offset, so every tool's TCP pose is the flange pose; the user frame is the base.
    def _m_get_base_flange_pose(self, p: dict) -> list[float]:
        return _in_unit(self._flange_pose(self.robot.snapshot().q), _unit_type(p))

    _m_get_user_flange_pose = _m_get_base_flange_pose

    def _m_get_tcp_pose(self, p: dict) -> list[float]:
        coord = p.get("coordinate_num", -1)
        tool = p.get("tool_num", -1)
        if not isinstance(coord, int) or isinstance(coord, bool) or not (-1 <= coord < N_TOOLS):
            raise RpcError(INVALID_PARAMS, "Invalid params: coordinate_num must be -1 (base) or 0..7 (user frame)")
        if not isinstance(tool, int) or isinstance(tool, bool) or not (-1 <= tool < N_TOOLS):
            raise RpcError(INVALID_PARAMS, "Invalid params: tool_num must be -1 (current) or 0..7")
        return _in_unit(self._flange_pose(self.robot.snapshot().q), _unit_type(p))

    # motion
    def _m_moveByJoint(self, p: dict) -> bool:
        target = p.get("targetPos")
        if not isinstance(target, list) or len(target) not in (6, 8) or not all(is_number(v) for v in target):
            raise RpcError(INVALID_PARAMS, "Invalid params: targetPos must be 6 or 8 numbers (deg)")
        speed = p.get("speed")
        if not is_number(speed) or not (SPEED_MIN_PCT <= float(speed) <= SPEED_MAX_PCT):
            raise RpcError(INVALID_PARAMS, f"Invalid params: speed must be in [{SPEED_MIN_PCT}, {SPEED_MAX_PCT}]")
        acc_dec = []
        for key in ("acc", "dec"):
            v = p.get(key, 0)
            if not is_number(v) or not (ACC_MIN_PCT <= float(v) <= ACC_MAX_PCT):
                raise RpcError(INVALID_PARAMS, f"Invalid params: {key} must be in [{ACC_MIN_PCT}, {ACC_MAX_PCT}]")
            acc_dec.append(float(v) if float(v) > 0 else 100.0)  # 0 / absent: controller default
        for key in ("cond_type", "cond_num", "cond_value"):
            if key in p and not isinstance(p[key], int):
                raise RpcError(INVALID_PARAMS, f"Invalid params: {key} must be an integer")
        target_rad = np.radians(np.asarray(target[:6], float))
        caps = lead_joint_caps(self.robot.snapshot().q, target_rad, self.joint_max_speed_rad_s,
                               self.joint_max_accel_rad_s2)
        # the sim has one acceleration for both ramps: the smaller of acc and dec
        v, a = lead_from_percent(caps, float(speed), min(acc_dec))
        with self._lock:
            if self._robot_state(self.robot.snapshot()) != STATE_STOP:
                return False  # alarm, e-stop, collision or already running: refused
            try:
                t0 = self.robot.now()
                dur = self.robot.move_joints(target_rad, v, a)
            except SimRefused:
                return False
            self._motion = {"t0": t0, "dur": dur, "seen": False}
        self.record_event("move", f"targetPos={[round(float(x), 4) for x in target[:6]]} speed={speed}")
        return True

    def _m_stop(self, p: dict) -> bool:
        self.record_event("stop")
        self.robot.stop()
        self._mark_motion_stopped()  # ends a "never_finish" motion too
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
        if not is_number(m) or not (0.0 <= float(m) <= self.max_payload_kg):
            raise RpcError(INVALID_PARAMS, f"Invalid params: m must be in [0, {self.max_payload_kg}] kg")
        cog = p.get("cog", p.get("point"))
        if not isinstance(cog, list) or len(cog) != 3 or not all(is_number(v) for v in cog):
            raise RpcError(INVALID_PARAMS, "Invalid params: cog must be [x, y, z] in mm")
        if any(abs(float(v)) > 5000.0 for v in cog):
            raise RpcError(INVALID_PARAMS, "Invalid params: cog components must be in [-5000, 5000] mm")
        with self._lock:
            self._payloads[n] = {"m": float(m), "tool_cog": [float(v) for v in cog]}
        self.record_event("payload", f"tool {n}: m={m} cog={cog}")
        return True

    def _m_get_tool_payload(self, p: dict) -> dict:
        return self.payload_setting(self._tool_num(p))

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
