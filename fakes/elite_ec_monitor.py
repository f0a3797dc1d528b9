"""Elite EC "monitor" port (TCP 8056) of the simulated controller.

The real controller pushes one fixed-layout, big-endian binary frame every 8 ms to
every client connected on port 8056 (docs.elibot.cn, "二次开发端口总结": 8056 =
monitor port, 8 ms period; frame layout from Elite's own Python library
JunJie-zhang-o/eliterobot ``elite/_monitor.py`` (``ECMonitorInfo._ec_struct``,
unpacked with ``"!"`` i.e. big-endian) and a complete 1024-byte decoder in a public
Node.js client (fields after ``jointacc``: jointTemperature, jointTorque,
extJointTorques, exTcpForceInTool, dragState, 220 reserved bytes, matchingWord).
See docs/sources.md, section "Elite EC".

Here a frame is sent every 8 ms of SIMULATED time: the server subscribes to the
SimRobot clock and emits whenever simulated time crosses the next 8 ms boundary.
Each client has its own sender thread and a bounded queue. A client that reads, but slower
than a fast simulation produces (50× real time on a loaded host), holds the simulation
thread back until its queue has room: simulated time is elastic, so the client sees the
stream a real controller would send in real time. A client that stops reading is
disconnected after ``BLOCK_LIMIT_S``, as a real controller closes a connection whose send
buffer stays full.
"""

from __future__ import annotations

import queue
import socket
import struct
import threading
import time
from typing import Mapping

from payload_agent.fakes.tcp_server import TCPServer, shutdown_socket

# (name, offset, struct type, count). Big-endian, no padding. Offsets verified by
# ``_check_layout`` at import time.
MONITOR_LAYOUT: tuple[tuple[str, int, str, int], ...] = (
    ("MessageSize", 0, "I", 1),  # u32, total frame length in bytes (1024)
    ("TimeStamp", 4, "Q", 1),  # u64, ms (real controller: ms since epoch; fake: sim time)
    ("autorun_cycleMode", 12, "B", 1),  # 0 step, 1 cycle, 2 continuous
    ("machinePos", 13, "d", 8),  # joint angles, deg
    ("machinePose", 77, "d", 6),  # TCP pose in base: mm, rad
    ("machineUserPose", 125, "d", 6),  # TCP pose in the user frame
    ("torque", 173, "d", 8),  # joint torque, % of rated torque
    ("robotState", 237, "i", 1),  # 0 stop 1 pause 2 e-stop 3 running 4 error 5 collision
    ("servoReady", 241, "i", 1),  # 1 servo on
    ("can_motor_run", 245, "i", 1),  # 1 encoders synchronized
    ("motor_speed", 249, "i", 8),  # rpm
    ("robotMode", 281, "i", 1),  # 0 teach 1 play 2 remote
    ("analog_ioInput", 285, "d", 3),
    ("analog_ioOutput", 309, "d", 5),
    ("digital_ioInput", 349, "Q", 1),  # bit mask X0..X63
    ("digital_ioOutput", 357, "Q", 1),  # bit mask Y0..Y63
    ("collision", 365, "B", 1),  # 1 collision alarm
    ("machineFlangePose", 366, "d", 6),
    ("machineUserFlangePose", 414, "d", 6),
    ("emergencyStopState", 462, "B", 1),  # 1 e-stop pressed
    ("tcp_speed", 463, "d", 1),
    ("joint_speed", 471, "d", 8),  # deg/s
    ("tcpacc", 535, "d", 1),
    ("jointacc", 543, "d", 8),  # deg/s^2
    ("joint_temperature", 607, "d", 6),
    ("jointTorque", 655, "d", 6),  # Nm (fake: the simulated joint torque)
    ("extJointTorques", 703, "d", 6),
    ("exTcpForceInTool", 751, "d", 6),
    ("dragState", 799, "B", 1),
    ("reserved", 800, "x", 220),
    ("matchingWord", 1020, "I", 1),
)

FRAME_SIZE = 1024
PERIOD_S = 0.008
MATCHING_WORD = 0  # value not documented publicly; the fake sends 0

_FIELDS = {name: (off, typ, n) for name, off, typ, n in MONITOR_LAYOUT}


def _check_layout() -> None:
    offset = 0
    for name, off, typ, n in MONITOR_LAYOUT:
        if off != offset:
            raise AssertionError(f"monitor layout: {name} at {off}, expected {offset}")
        offset += struct.calcsize(f"!{n}{typ}")
    if offset != FRAME_SIZE:
        raise AssertionError(f"monitor layout adds up to {offset} bytes, not {FRAME_SIZE}")


_check_layout()


def pack_frame(values: Mapping[str, object]) -> bytes:
    """One 1024-byte frame; fields missing from ``values`` are zero."""
    buf = bytearray(FRAME_SIZE)
    for name, (off, typ, n) in _FIELDS.items():
        if typ == "x":
            continue
        if name == "MessageSize":
            v: object = FRAME_SIZE
        elif name == "matchingWord":
            v = values.get(name, MATCHING_WORD)
        else:
            v = values.get(name)
        if v is None:
            continue
        if n == 1:
            struct.pack_into(f"!{typ}", buf, off, v)
        else:
            seq = list(v)  # type: ignore[arg-type]
            seq = (seq + [0] * n)[:n]
            struct.pack_into(f"!{n}{typ}", buf, off, *seq)
    return bytes(buf)


def unpack_frame(frame: bytes) -> dict[str, object]:
    """Decode a frame into a dict (arrays as lists); used by tests."""
    if len(frame) < FRAME_SIZE:
        raise ValueError(f"frame of {len(frame)} bytes, expected {FRAME_SIZE}")
    out: dict[str, object] = {}
    for name, (off, typ, n) in _FIELDS.items():
        if typ == "x":
            continue
        vals = struct.unpack_from(f"!{n}{typ}", frame, off)
        out[name] = vals[0] if n == 1 else list(vals)
    return out


class _Client:
    """One monitor client: frames queued by the simulation thread, sent by the connection's thread."""

    def __init__(self, sock: socket.socket, max_queue: int):
        self.sock = sock
        self.queue: queue.Queue[bytes | None] = queue.Queue(maxsize=max_queue)
        self.dead = threading.Event()
        self.lagged = False  # dropped because it fell too far behind
        self.counted = False  # counted in MonitorServer.dropped_clients

    def run(self) -> None:
        """The sender loop (runs on the TCP server's connection thread until dropped)."""
        try:
            while not self.dead.is_set():
                frame = self.queue.get()
                if frame is None:
                    break
                self.sock.sendall(frame)
        finally:
            self.dead.set()

    def offer(self, frame: bytes) -> bool:
        """Queue a frame, waiting up to ``BLOCK_LIMIT_S`` for room; False when the client does not read
        (it is then dropped) or was dropped."""
        deadline = time.monotonic() + BLOCK_LIMIT_S
        while not self.dead.is_set():
            try:
                self.queue.put(frame, timeout=0.05)
                return True
            except queue.Full:
                if time.monotonic() > deadline:
                    self.lagged = True
                    self.drop()
        return False

    def drop(self) -> None:
        self.dead.set()
        shutdown_socket(self.sock)  # wakes a sender blocked in sendall
        try:
            self.queue.put_nowait(None)  # wakes a sender waiting for a frame
        except queue.Full:
            pass


SEND_BUFFER_BYTES = 32 * 1024
BLOCK_LIMIT_S = 2.0  # wall time a full queue may hold the simulation back before its client is dropped


class MonitorServer:
    """Accepts clients on the monitor port (``fakes.tcp_server``) and fans frames out to them."""

    def __init__(self, host: str, port: int, max_queue: int = 1000):
        # max_queue frames (8 s of simulated time) queued behind a full socket buffer before a
        # client is dropped
        self.max_queue = max_queue
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self.dropped_clients = 0
        self._closed = False
        self._server = TCPServer(host, port, self._serve, name="elite-monitor")
        self.port = self._server.port

    def start(self) -> None:
        self._server.start()

    def _serve(self, sock: socket.socket, addr) -> None:
        # a small kernel send buffer, as on an embedded controller: a client that stops reading
        # backs up into the bounded queue within a second, not after megabytes of autotuned buffer
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        client = _Client(sock, self.max_queue)
        with self._lock:
            if self._closed:
                return
            self._clients.append(client)
        try:
            client.run()
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)

    def has_clients(self) -> bool:
        with self._lock:
            return bool(self._clients)

    def broadcast(self, frame: bytes) -> None:
        """Called from the simulation thread: never blocks."""
        with self._lock:
            clients = list(self._clients)
        gone = []
        for c in clients:
            if not c.offer(frame):
                gone.append(c)
        if gone:
            with self._lock:
                for c in gone:
                    if c in self._clients:
                        self._clients.remove(c)
                    # counted here even when its connection thread already removed it (it wakes
                    # as soon as drop() shuts the socket down, and may get there first)
                    if c.lagged and not c.counted:
                        c.counted = True
                        self.dropped_clients += 1

    def drop_connections(self) -> None:
        """Close every client connection; the port keeps accepting new ones."""
        with self._lock:
            clients, self._clients = self._clients, []
        for c in clients:
            c.drop()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            clients, self._clients = self._clients, []
        for c in clients:
            c.drop()
        self._server.close()
