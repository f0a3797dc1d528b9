"""What the simulated UR controller outputs in one control cycle, and how RTDE reads each field.

``Snapshot`` is built once per tick by the controller (``controller.URControllerCore._on_tick``)
and shared by every RTDE session; ``GETTERS`` maps each RTDE output name to a function of it.
Costly fields (the model torque, the TCP pose) are computed only when a recipe asks for them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from payload_agent.fakes import ur_rtde_protocol as rp
from payload_agent.fakes.ur.constants import (JOINT_MODE_POWER_OFF, JOINT_MODE_RUNNING, ROBOT_MODE_IDLE,
                                              ROBOT_MODE_POWER_ON, ROBOT_MODE_RUNNING, RSB_POWER_ON,
                                              RSB_PROGRAM_RUNNING, RUNTIME_PLAYING)

if TYPE_CHECKING:
    from payload_agent.fakes.sim_robot import SimState
    from payload_agent.fakes.ur.controller import URControllerCore

_NAN6 = np.full(6, np.nan)


class Snapshot:
    """The controller's outputs in one control cycle (immutable once built)."""

    __slots__ = ("ctrl", "t", "t_exact", "q", "qd", "qdd", "tau", "current", "moving", "robot_mode", "safety_mode",
                 "safety_bits", "runtime_state", "robot_status_bits", "out_int", "out_dbl", "in_int", "in_dbl",
                 "out_bits", "in_bits", "digital_in", "joint_temps", "payload_mass", "payload_cog", "payload_inertia",
                 "tcp_offset", "_cache")

    ctrl: "URControllerCore"

    def lazy(self, key: str, fn: Callable[[], Any]) -> Any:
        if self._cache is None:
            self._cache = {}
        if key not in self._cache:
            self._cache[key] = fn()
        return self._cache[key]


def build_snapshot(ctrl: "URControllerCore", st: "SimState", current: np.ndarray, nan: bool = False) -> Snapshot:
    """The controller's outputs for one tick of the simulation (``nan``: the nan_values fault)."""
    s = Snapshot()
    s.ctrl = ctrl
    s.t, s.q, s.qd, s.qdd, s.tau, s.moving = st.t, st.q, st.qd, st.qdd, st.torque_nm, st.moving
    s.t_exact = st.t_true if st.t_true is not None else st.t  # s.t is reported, with timestamp jitter
    s.current = current
    if nan:
        s.q, s.qd, s.current = _NAN6, _NAN6, _NAN6
    s._cache = None
    s.joint_temps = ctrl.advance_temperatures(s.t_exact)
    with ctrl.lock:
        s.safety_mode, s.safety_bits = ctrl.safety(st)
        s.robot_mode = ctrl.robot_mode
        s.runtime_state = ctrl.runtime_state
        powered = ctrl.robot_mode in (ROBOT_MODE_POWER_ON, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING)
        s.robot_status_bits = ((1 << RSB_POWER_ON) if powered else 0) | \
            ((1 << RSB_PROGRAM_RUNNING) if ctrl.runtime_state == RUNTIME_PLAYING else 0)
        s.out_int, s.out_dbl = tuple(ctrl.out_int), tuple(ctrl.out_dbl)
        s.in_int, s.in_dbl = tuple(ctrl.in_int), tuple(ctrl.in_dbl)
        s.out_bits, s.in_bits, s.digital_in = ctrl.out_bits, ctrl.in_bits, ctrl.digital_in
        s.payload_mass, s.payload_cog, s.payload_inertia = ctrl.payload_mass, ctrl.payload_cog, ctrl.payload_inertia
        s.tcp_offset = ctrl.tcp_offset
    return s


class TcpPose:
    """actual_TCP_pose from joint angles, fast enough for every package at 500 Hz × the time scale.

    The standard-DH chain (frame i from i-1: Rz(q + offset) Tz(d) Tx(a) Rx(alpha), as
    ``payload_agent.model.kinematics``) in plain floats, times the TCP offset; the TCP's
    matrix is cached, and so is the last pose (the arm often stands still).
    """

    def __init__(self, dh_rows):
        self.rows = [(r.a_m, r.d_m, math.cos(r.alpha_rad), math.sin(r.alpha_rad), r.offset_rad) for r in dh_rows]
        self._tcp_key: tuple | None = None
        self._tcp: list[list[float]] = []
        self._last: tuple | None = None

    def flange(self, q: Sequence[float]) -> list[list[float]]:
        """The 3x4 flange transform [R | p] (rows) of the base frame."""
        T = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
        for qi, (a, d, ca, sa, off) in zip(q, self.rows):
            ct, st = math.cos(qi + off), math.sin(qi + off)
            A = ((ct, -st * ca, st * sa, a * ct), (st, ct * ca, -ct * sa, a * st), (0.0, sa, ca, d))
            T = [[r[0] * A[0][0] + r[1] * A[1][0] + r[2] * A[2][0],
                  r[0] * A[0][1] + r[1] * A[1][1] + r[2] * A[2][1],
                  r[0] * A[0][2] + r[1] * A[1][2] + r[2] * A[2][2],
                  r[0] * A[0][3] + r[1] * A[1][3] + r[2] * A[2][3] + r[3]] for r in T]
        return T

    def pose(self, q: Sequence[float], tcp_offset: Sequence[float]) -> tuple[float, ...]:
        key = (tuple(float(v) for v in q), tuple(tcp_offset))
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        if self._tcp_key != key[1]:
            self._tcp_key, self._tcp = key[1], pose_to_matrix(tcp_offset)[:3].tolist()
        F, C = self.flange(key[0]), self._tcp
        T = [[f[0] * C[0][j] + f[1] * C[1][j] + f[2] * C[2][j] for j in range(4)] for f in F]
        pose = (T[0][3] + F[0][3], T[1][3] + F[1][3], T[2][3] + F[2][3], *_rotvec(T))
        self._last = (key, pose)
        return pose


def _rotvec(R: list[list[float]]) -> tuple[float, float, float]:
    """Rotation matrix (the 3x3 part of R) -> rotation vector (angle in [0, π]), as UR poses carry it."""
    v = (R[2][1] - R[1][2], R[0][2] - R[2][0], R[1][0] - R[0][1])  # 2 sin(angle) · axis
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    c = (R[0][0] + R[1][1] + R[2][2] - 1.0) / 2.0
    if n < 1e-4 and c < 0:  # angle near π: the axis is not in v
        return tuple(float(x) for x in Rotation.from_matrix(np.asarray(R)[:3, :3]).as_rotvec())
    if n == 0.0:
        return (0.0, 0.0, 0.0)
    k = math.atan2(n / 2.0, c) / n
    return (v[0] * k, v[1] * k, v[2] * k)


def pose_to_matrix(pose: Sequence[float]) -> np.ndarray:
    """UR pose [x, y, z, rx, ry, rz] (m, rotation vector) -> 4x4 homogeneous transform."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.asarray(pose[3:6], float)).as_matrix()
    T[:3, 3] = np.asarray(pose[:3], float)
    return T


def _const(value: Any) -> Callable[[Snapshot], Any]:
    return lambda s: value


def _tcp(s: Snapshot) -> tuple[float, ...]:
    return s.lazy("tcp", lambda: s.ctrl.tcp_pose(s.q, s.tcp_offset))


def _model(s: Snapshot) -> np.ndarray:
    return s.lazy("model", lambda: s.ctrl.own_model.moment(s.q, s.qd, s.qdd))


def _target_current(s: Snapshot) -> np.ndarray:
    return s.lazy("target_current", lambda: s.ctrl.own_model.current(_model(s), s.qd))


def _build_getters() -> dict[str, Callable[[Snapshot], Any]]:
    z6 = (0.0,) * 6
    g: dict[str, Callable[[Snapshot], Any]] = {
        "timestamp": lambda s: s.t,
        "target_q": lambda s: s.q,
        "target_qd": lambda s: s.qd,
        "target_qdd": lambda s: s.qdd,
        "target_moment": _model,
        "target_current": _target_current,
        "actual_q": lambda s: s.q,
        "actual_qd": lambda s: s.qd,
        "actual_current": lambda s: s.current,
        "actual_current_window": _const((0.5,) * 6),
        "actual_current_as_torque": lambda s: s.current * s.ctrl.gains,
        "joint_control_output": lambda s: s.current,
        "actual_TCP_pose": _tcp,
        "target_TCP_pose": _tcp,
        "tcp_offset": lambda s: s.tcp_offset,
        "actual_TCP_speed": _const(z6),
        "target_TCP_speed": _const(z6),
        "actual_TCP_force": _const(z6),
        "ft_raw_wrench": _const(z6),
        "joint_temperatures": lambda s: s.joint_temps,
        "actual_execution_time": _const(0.3),
        "robot_mode": lambda s: s.robot_mode,
        "joint_mode": lambda s: (JOINT_MODE_RUNNING if s.robot_mode == ROBOT_MODE_RUNNING
                                 else JOINT_MODE_POWER_OFF,) * 6,
        "safety_mode": lambda s: s.safety_mode,
        "safety_status": lambda s: s.safety_mode,
        "actual_tool_accelerometer": _const((0.0, 0.0, 9.81)),
        "speed_scaling": _const(1.0),
        "target_speed_fraction": _const(1.0),
        "actual_momentum": _const(0.0),
        "actual_main_voltage": _const(48.0),
        "actual_robot_voltage": lambda s: 48.0 if s.robot_mode in (ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING) else 0.0,
        "actual_robot_current": lambda s: float(np.sum(np.abs(s.current))) * 0.1,
        "actual_joint_voltage": _const((47.5,) * 6),
        "runtime_state": lambda s: s.runtime_state,
        "robot_status_bits": lambda s: s.robot_status_bits,
        "safety_status_bits": lambda s: s.safety_bits,
        "output_bit_registers0_to_31": lambda s: s.out_bits & 0xFFFFFFFF,
        "output_bit_registers32_to_63": lambda s: (s.out_bits >> 32) & 0xFFFFFFFF,
        "input_bit_registers0_to_31": lambda s: s.in_bits & 0xFFFFFFFF,
        "input_bit_registers32_to_63": lambda s: (s.in_bits >> 32) & 0xFFFFFFFF,
        "actual_digital_input_bits": lambda s: s.digital_in,
        "payload": lambda s: s.payload_mass,
        "payload_cog": lambda s: s.payload_cog,
        "payload_inertia": lambda s: s.payload_inertia,
        "tool_output_voltage": _const(0),
        "tool_temperature": _const(30.0),
    }
    for i in range(48):
        g[f"output_int_register_{i}"] = (lambda i: lambda s: s.out_int[i])(i)
        g[f"output_double_register_{i}"] = (lambda i: lambda s: s.out_dbl[i])(i)
        g[f"input_int_register_{i}"] = (lambda i: lambda s: s.in_int[i])(i)
        g[f"input_double_register_{i}"] = (lambda i: lambda s: s.in_dbl[i])(i)
    for i in range(64, 128):
        g[f"output_bit_register_{i}"] = (lambda i: lambda s: bool((s.out_bits >> i) & 1))(i)
        g[f"input_bit_register_{i}"] = (lambda i: lambda s: bool((s.in_bits >> i) & 1))(i)
    defaults = {"BOOL": False, "UINT8": 0, "UINT32": 0, "UINT64": 0, "INT32": 0, "DOUBLE": 0.0,
                "VECTOR3D": (0.0,) * 3, "VECTOR6D": z6, "VECTOR6INT32": (0,) * 6, "VECTOR6UINT32": (0,) * 6}
    for name, typ in rp.OUTPUT_TYPES.items():
        g.setdefault(name, _const(defaults[typ]))
    return g


GETTERS = _build_getters()
