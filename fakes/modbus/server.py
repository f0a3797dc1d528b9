"""The pymodbus server of a simulated Modbus robot, in a thread of its own, over TCP or RTU.

TCP: a ``ModbusTcpServer`` on a loopback address and an ephemeral port.
RTU: a ``ModbusSerialServer`` on one end of ``PtyLink``, two pseudo-terminal pairs joined by a
thread like a serial cable (no socat): bytes cross at the configured baud rate (10 bits per
byte, 8N1), so an RTU request takes as long as on a real line.

Fault hooks: ``drop_replies`` (requests are swallowed: the client times out),
``drop_connections()`` (TCP: every client connection is closed, new ones are accepted;
RTU: the line is cut for a moment).
"""

from __future__ import annotations

import asyncio
import os
import select
import threading
import time
import tty

from pymodbus import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from payload_agent.fakes.modbus.store import RegisterStore


class PtyLink:
    """Two pty pairs joined like a null-modem cable; ``server_path`` and ``client_path`` are the ends."""

    def __init__(self, baudrate: int, bits_per_byte: int = 10):
        self.byte_s = bits_per_byte / float(baudrate)
        self._m_server, self._s_server = os.openpty()
        self._m_client, self._s_client = os.openpty()
        for fd in (self._s_server, self._s_client):
            tty.setraw(fd)  # no echo, no line editing before the application opens it
        self.server_path = os.ttyname(self._s_server)
        self.client_path = os.ttyname(self._s_client)
        self._running = threading.Event()
        self._cut_until = 0.0
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        self._running.set()
        for src, dst, name in ((self._m_client, self._m_server, "to-server"),
                               (self._m_server, self._m_client, "to-client")):
            th = threading.Thread(target=self._forward, args=(src, dst), name=f"pty-{name}", daemon=True)
            th.start()
            self._threads.append(th)

    def cut(self, seconds: float) -> None:
        """Drop every byte for ``seconds`` (a cable pulled and plugged back)."""
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
            now = time.monotonic()
            line_free = max(line_free, now) + len(data) * self.byte_s
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
        for fd in (self._m_server, self._s_server, self._m_client, self._s_client):
            try:
                os.close(fd)
            except OSError:
                pass


class ModbusServerThread:
    """Runs the pymodbus server for ``store`` in its own event loop thread."""

    def __init__(self, store: RegisterStore, transport: str = "tcp", host: str = "127.0.0.1",
                 baudrate: int = 115200):
        self.store = store
        self.transport = transport
        self.host = host
        self.port = 0
        self.baudrate = baudrate
        self.link: PtyLink | None = PtyLink(baudrate) if transport == "rtu" else None
        self.drop_replies = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    @property
    def client_path(self) -> str | None:
        return self.link.client_path if self.link else None

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending and self.drop_replies:
            return b""
        return data

    def start(self) -> "ModbusServerThread":
        if self.link:
            self.link.start()
        self._thread = threading.Thread(target=self._run, name=f"modbus-{self.transport}-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(5.0):
            raise RuntimeError("the simulated Modbus server did not start within 5 s")
        if self._error is not None:
            raise RuntimeError(f"the simulated Modbus server failed to start: {self._error}") from self._error
        return self

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        loop.run_forever()
        loop.run_until_complete(loop.shutdown_asyncgens())
        loop.close()

    async def _serve(self) -> None:
        dummy = SimDevice(0, simdata=[SimData(0, datatype=DataType.UINT16)])
        if self.transport == "tcp":
            server = ModbusTcpServer(dummy, address=(self.host, 0), trace_packet=self._trace_packet)
        else:
            server = ModbusSerialServer(dummy, framer=FramerType.RTU, port=self.link.server_path,
                                        baudrate=self.baudrate, trace_packet=self._trace_packet,
                                        ignore_missing_devices=True)
        server.context = self.store  # our datastore answers every request (see store.RegisterStore)
        await server.serve_forever(background=True)
        self._server = server
        if self.transport == "tcp":
            self.port = server.transport.sockets[0].getsockname()[1]

    def drop_connections(self, cut_s: float = 0.3) -> None:
        if self.link is not None:
            self.link.cut(cut_s)
            return
        server = self._server

        def close_all() -> None:
            for conn in list(server.active_connections.values()):
                conn.close()

        if self._loop is not None and server is not None:
            self._loop.call_soon_threadsafe(close_all)

    def close(self) -> None:
        loop, server = self._loop, self._server
        if loop is not None and server is not None and loop.is_running():
            async def shutdown() -> None:
                await server.shutdown()
                pending = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
                for task in pending:  # requests still waiting (slow_reply): dropped with the server
                    task.cancel()
                await asyncio.gather(*pending, return_exceptions=True)

            fut = asyncio.run_coroutine_threadsafe(shutdown(), loop)
            try:
                fut.result(timeout=2.0)
            except Exception:
                pass
            loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self.link is not None:
            self.link.close()
