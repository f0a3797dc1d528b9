"""The Elite EC monitor port (8056): a big-endian binary frame pushed every 8 ms.

The first field (u32 MessageSize) gives the frame length (1024 bytes on current firmware);
the driver frames the byte stream on it and decodes the fields it needs. The offsets are
the public layout (docs/sources.md, "Elite EC"); they are written out here on purpose, apart
from the simulated controller's table (fakes/elite_ec_monitor.py), so that a layout mistake
in one shows up as a test failure against the other.
"""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass

from payload_agent.errors import CommunicationError

PERIOD_S = 0.008
_TIMESTAMP = (4, "!Q")  # ms
_MACHINE_POS = (13, "!8d")  # joint angles, deg
_TORQUE = (173, "!8d")  # percent of rated torque
_ROBOT_STATE = (237, "!i")
_SERVO_READY = (241, "!i")
_ROBOT_MODE = (281, "!i")
_COLLISION = (365, "!B")
_FLANGE_POSE = (366, "!6d")  # machineFlangePose: flange in the base frame, mm and rad (x, y, z, rx, ry, rz)
_ESTOP = (462, "!B")
MIN_SIZE = 463  # every field above ends before this offset
# joint_temperature, 6 doubles in °C: in the 1024-byte frame's tail (after jointacc), which Elite's own library
# does not decode; read only from frames long enough to hold it.
_JOINT_TEMP = (607, "!6d")
_JOINT_TEMP_END = 607 + 48
MAX_SIZE = 1 << 16


@dataclass(frozen=True)
class MonitorFrame:
    """The fields of one monitor frame the driver uses, in the controller's own units."""

    t_recv: float  # time.monotonic() when the bytes arrived
    timestamp_ms: int
    joint_deg: tuple[float, ...]  # 8 values, joints 7 and 8 unused
    torque_pct: tuple[float, ...]  # 8 values
    robot_state: int
    servo_ready: int
    robot_mode: int
    collision: int
    estop: int
    flange_pose: tuple[float, ...]  # mm, mm, mm, rad, rad, rad
    joint_temperature: tuple[float, ...] | None  # None: the frame is too short to hold it


def decode_frame(frame: bytes, t_recv: float) -> MonitorFrame:
    def get(field):
        off, fmt = field
        return struct.unpack_from(fmt, frame, off)

    temps = get(_JOINT_TEMP) if len(frame) >= _JOINT_TEMP_END else None
    return MonitorFrame(t_recv, get(_TIMESTAMP)[0], get(_MACHINE_POS), get(_TORQUE), get(_ROBOT_STATE)[0],
                        get(_SERVO_READY)[0], get(_ROBOT_MODE)[0], get(_COLLISION)[0], get(_ESTOP)[0],
                        get(_FLANGE_POSE), temps)


class MonitorStream:
    """One connection to the monitor port; ``read`` returns the frames that have arrived."""

    def __init__(self, host: str, port: int, connect_timeout_s: float):
        self.endpoint = f"{host}:{port}"
        try:
            self._sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as e:
            raise CommunicationError(
                f"cannot connect to the Elite controller's monitor port {host}:{port}: {e}. "
                'Check the port, or set driver.sample_source: "poll" to sample over the JSON-RPC port.') from e
        self._buf = bytearray()

    def read(self, timeout_s: float) -> list[MonitorFrame]:
        """Frames completed by the bytes that arrive within ``timeout_s`` (possibly none).

        Raises CommunicationError when the controller closed the port or sent something that
        is not an Elite monitor stream.
        """
        self._sock.settimeout(timeout_s)
        try:
            chunk = self._sock.recv(65536)
        except socket.timeout:
            return []
        except OSError as e:
            raise CommunicationError(f"the monitor port {self.endpoint} failed: {e}") from e
        if not chunk:
            raise CommunicationError(f"the controller closed the monitor port {self.endpoint}")
        t_recv = time.monotonic()
        self._buf += chunk
        frames = []
        while len(self._buf) >= 4:
            size = struct.unpack_from("!I", self._buf, 0)[0]
            if not (MIN_SIZE <= size <= MAX_SIZE):
                raise CommunicationError(
                    f"the monitor port {self.endpoint} sent a frame announcing {size} bytes: this is not an "
                    f"Elite EC monitor stream (or it lost sync); first bytes {bytes(self._buf[:16])!r}")
            if len(self._buf) < size:
                break
            frame = bytes(self._buf[:size])
            del self._buf[:size]
            frames.append(decode_frame(frame, t_recv))
        return frames

    def close(self) -> None:
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        try:
            self._sock.close()
        except OSError:
            pass
