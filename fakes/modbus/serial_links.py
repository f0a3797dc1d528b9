"""The serial line between the agent and a simulated Modbus RTU device, in two forms a cell has.

``PtyLink``: two pseudo-terminal pairs joined like a null-modem cable; the agent opens a tty path, as it
would a USB-RS485 adapter's ``/dev/ttyUSB0``.

``DeviceServerLink``: a serial device server in raw TCP server mode (e.g. a Moxa NPort, docs/sources.md):
the agent connects to its TCP data port (pyserial's ``socket://host:port``) and the device server puts the
bytes on the serial line to the device. The device end here is the device's own listening socket (pymodbus'
serial server given a ``socket://`` port), so no pty is involved.

Both carry bytes at the configured baud rate (10 bits per byte, 8N1), so an RTU request takes as long as on
a real line, and both can be cut for a moment (a cable pulled and plugged back): bytes are then lost.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
import tty


class SerialLine:
    """Bytes between pairs of file descriptors, paced at the baud rate, each direction in a thread of its own."""

    def __init__(self, baudrate: int, bits_per_byte: int = 10):
        self.byte_s = bits_per_byte / float(baudrate)
        self._running = threading.Event()
        self._running.set()
        self._cut_until = 0.0
        self._threads: list[threading.Thread] = []

    def join(self, a: int, b: int, name: str) -> None:
        """Carry bytes both ways between ``a`` and ``b`` until closed or either end is gone."""
        for src, dst, way in ((a, b, "out"), (b, a, "back")):
            th = threading.Thread(target=self._forward, args=(src, dst), name=f"{name}-{way}", daemon=True)
            th.start()
            self._threads.append(th)

    def cut(self, seconds: float) -> None:
        """Drop every byte for ``seconds``."""
        self._cut_until = time.monotonic() + seconds

    def _forward(self, src: int, dst: int) -> None:
        line_free = 0.0
        while self._running.is_set():
            try:
                ready, _, _ = select.select([src], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(src, 4096)
            except OSError:
                return
            if not data:  # a socket end closed
                return
            line_free = max(line_free, time.monotonic()) + len(data) * self.byte_s
            delay = line_free - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if time.monotonic() < self._cut_until:
                continue
            try:
                os.write(dst, data)
            except OSError:
                return

    def close(self) -> None:
        self._running.clear()
        for th in self._threads:
            th.join(timeout=1.0)


class PtyLink(SerialLine):
    """Two pty pairs joined like a null-modem cable; ``server_path`` and ``client_path`` are the ends."""

    def __init__(self, baudrate: int, bits_per_byte: int = 10):
        super().__init__(baudrate, bits_per_byte)
        self._m_server, self._s_server = os.openpty()
        self._m_client, self._s_client = os.openpty()
        for fd in (self._s_server, self._s_client):
            tty.setraw(fd)  # no echo, no line editing before the application opens it
        self.server_path = os.ttyname(self._s_server)
        self.client_path = os.ttyname(self._s_client)

    def start(self, device_address: tuple[str, int] | None = None) -> None:
        """Join the two ends (a tty has no device address: the device opens ``server_path``)."""
        self.join(self._m_client, self._m_server, "pty")

    def close(self) -> None:
        super().close()
        for fd in (self._m_server, self._s_server, self._m_client, self._s_client):
            try:
                os.close(fd)
            except OSError:
                pass


class DeviceServerLink(SerialLine):
    """A serial device server's TCP data port on ``host``; ``client_path`` is the pyserial URL the agent opens.

    Each accepted connection gets a line of its own to the device (``start``'s ``device_address``), as the
    device server opens the serial port anew for each TCP client it accepts.
    """

    server_path = "socket://127.0.0.1:0"  # where the device listens: an ephemeral port, known once it listens

    def __init__(self, baudrate: int, host: str = "127.0.0.1", bits_per_byte: int = 10):
        super().__init__(baudrate, bits_per_byte)
        self._listener = socket.create_server((host, 0))
        self.client_path = "socket://%s:%d" % self._listener.getsockname()[:2]
        self._sockets: list[socket.socket] = []
        self._device: tuple[str, int] | None = None

    def start(self, device_address: tuple[str, int] | None = None) -> None:
        self._device = device_address
        th = threading.Thread(target=self._accept, name="device-server-accept", daemon=True)
        th.start()
        self._threads.append(th)

    def _accept(self) -> None:
        self._listener.settimeout(0.1)
        while self._running.is_set():
            try:
                agent, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                device = socket.create_connection(self._device, timeout=2.0)
            except OSError:  # the device is gone: the device server drops the client
                agent.close()
                continue
            for s in (agent, device):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._sockets.append(s)
            self.join(agent.fileno(), device.fileno(), "device-server")

    def close(self) -> None:
        self._running.clear()
        self._listener.close()
        for s in self._sockets:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        super().close()
        for s in self._sockets:
            s.close()
