"""Universal Robots RTDE wire format: package types, field types and packing.

Shared by the fake UR controller (``payload_agent.fakes.ur``) and its
tests. Everything is big-endian. A package is ``uint16 size`` (header included) +
``uint8 type`` + payload.

Numbers verified against (see docs/sources.md, "UR / ur_rtde"):

- ur_rtde 1.6.0 sources (sdurobotics/ur_rtde, release commit 85c55de, read through
  the GitHub fork gu002913/ur_rtde-fork-custom; the installed wheel is 1.6.5, whose
  embedded control script and client strings match these files):
  ``include/ur_rtde/rtde.h`` (command letters V=86 v=118 M=77 U=85 O=79 I=73 S=83
  P=80), ``src/rtde.cpp`` (HEADER_SIZE 3, protocol version 2 requested, output
  setup payload = IEEE double frequency + comma-joined names with a trailing comma,
  replies parsed from byte 1 on: ``data[0]`` is the recipe id, the rest the
  comma-separated types; "NOT_FOUND" and "IN_USE" are matched as substrings),
  ``src/robot_state.cpp`` (the client's own name -> C++ type table: it decodes a
  data package by that table, not by the types the controller announced, and
  ``payload_cog``/``actual_tool_accelerometer``/``elbow_*`` as 3 doubles).
- UR's RTDE guide (docs.universal-robots.com, "Real-Time Data Exchange (RTDE)
  Guide"): field names and types, text message layout of protocol version 2.
"""

from __future__ import annotations

import socket
import struct
from typing import Any, Iterable

HEADER = struct.Struct(">HB")
HEADER_SIZE = 3

# package types (ASCII letters), include/ur_rtde/rtde.h enum RTDECommand
REQUEST_PROTOCOL_VERSION = 86  # 'V'
GET_URCONTROL_VERSION = 118  # 'v'
TEXT_MESSAGE = 77  # 'M'
DATA_PACKAGE = 85  # 'U'
CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # 'O'
CONTROL_PACKAGE_SETUP_INPUTS = 73  # 'I'
CONTROL_PACKAGE_START = 83  # 'S'
CONTROL_PACKAGE_PAUSE = 80  # 'P'

# text message warning levels (protocol v2)
MSG_EXCEPTION, MSG_ERROR, MSG_WARNING, MSG_INFO = 0, 1, 2, 3

# field type name -> struct format (without byte order)
TYPE_FORMATS: dict[str, str] = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
VECTOR_LEN = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}


def _registers(prefix: str, typ: str, lo: int, hi: int) -> dict[str, str]:
    return {f"{prefix}{i}": typ for i in range(lo, hi + 1)}


# Controller outputs (RTDE guide, e-Series). Value: type. Only names listed here are
# accepted; anything else is answered with NOT_FOUND, as the real controller does.
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "actual_current_window": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "tcp_offset": "VECTOR6D",  # the installation's TCP in the flange frame (UR client library's RTDE type table)
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D",
    "script_control_line": "UINT32",
    "ft_raw_wrench": "VECTOR6D",
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    "actual_current_as_torque": "VECTOR6D",
    **_registers("output_bit_register_", "BOOL", 64, 127),
    **_registers("output_int_register_", "INT32", 0, 47),
    **_registers("output_double_register_", "DOUBLE", 0, 47),
    **_registers("input_bit_register_", "BOOL", 64, 127),
    **_registers("input_int_register_", "INT32", 0, 47),
    **_registers("input_double_register_", "DOUBLE", 0, 47),
}

# Outputs that only exist from some PolyScope version on, per major version (3 = CB3,
# 5 = e-Series); a series not listed does not have the field at all (ur_rtde's
# RTDEReceiveInterface::setupRecipes makes the same version checks).
OUTPUT_MIN_VERSION: dict[str, dict[int, tuple[int, int, int]]] = {
    "payload": {3: (3, 11, 0), 5: (5, 5, 1)},
    "payload_cog": {3: (3, 11, 0), 5: (5, 5, 1)},
    "payload_inertia": {3: (3, 15, 0), 5: (5, 11, 0)},
    "ft_raw_wrench": {5: (5, 9, 0)},
    "actual_current_as_torque": {5: (5, 23, 0)},
}


def output_available(name: str, version: tuple[int, ...]) -> bool:
    """Whether a controller of ``version`` (major, minor, bugfix, ...) knows output ``name``."""
    if name not in OUTPUT_TYPES:
        return False
    need = OUTPUT_MIN_VERSION.get(name)
    if need is None:
        return True
    major = version[0]
    if major in need:
        return tuple(version[:3]) >= need[major]
    return major > max(need)


# Controller inputs (RTDE guide). Register names are shared with the outputs above
# (a client may read back the input registers).
INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
    **_registers("input_bit_register_", "BOOL", 64, 127),
    **_registers("input_int_register_", "INT32", 0, 47),
    **_registers("input_double_register_", "DOUBLE", 0, 47),
}


def recipe_struct(types: Iterable[str]) -> struct.Struct:
    """Struct for a data package payload: uint8 recipe id + the fields in order."""
    return struct.Struct(">B" + "".join(TYPE_FORMATS[t] for t in types))


def flatten(types: Iterable[str], values: Iterable[Any]) -> list[Any]:
    out: list[Any] = []
    for t, v in zip(types, values):
        if t in VECTOR_LEN:
            out.extend(v)
        else:
            out.append(v)
    return out


def unflatten(types: Iterable[str], flat: Iterable[Any]) -> list[Any]:
    it = iter(flat)
    out: list[Any] = []
    for t in types:
        n = VECTOR_LEN.get(t)
        out.append(tuple(next(it) for _ in range(n)) if n else next(it))
    return out


def pack(kind: int, payload: bytes = b"") -> bytes:
    return HEADER.pack(HEADER_SIZE + len(payload), kind) + payload


def text_message(message: str, source: str = "RTDE", level: int = MSG_ERROR) -> bytes:
    """RTDE_TEXT_MESSAGE, protocol version 2 layout."""
    m = message.encode()[:255]
    s = source.encode()[:255]
    return pack(TEXT_MESSAGE, bytes([len(m)]) + m + bytes([len(s)]) + s + bytes([level]))


def recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        buf += chunk
    return bytes(buf)


def recv_package(sock: socket.socket) -> tuple[int, int, bytes]:
    """Read one package: (declared size, type, payload). Raises ValueError on a size < 3."""
    size, kind = HEADER.unpack(recv_exact(sock, HEADER_SIZE))
    if size < HEADER_SIZE:
        raise ValueError(f"package size {size} is smaller than the header")
    return size, kind, recv_exact(sock, size - HEADER_SIZE)
