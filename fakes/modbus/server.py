"""The pymodbus server of a simulated Modbus robot, in a thread of its own, over TCP or RTU.

TCP: a ``ModbusTcpServer`` on a loopback address and an ephemeral port.
RTU: a ``ModbusSerialServer`` at the device end of a serial line (``serial_links``): a pty pair the
agent opens as a tty, or a serial device server's TCP port (``socket://``) in front of it. Bytes cross
at the configured baud rate, so an RTU request takes as long as on a real line.

Fault hooks: ``drop_replies`` (requests are swallowed: the client times out),
``drop_connections()`` (TCP: every client connection is closed, new ones are accepted;
RTU: the line is cut for a moment).
"""

from __future__ import annotations

import asyncio
import threading

from pymodbus import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from payload_agent.fakes.modbus.serial_links import DeviceServerLink, PtyLink
from payload_agent.fakes.modbus.store import RegisterStore


class ModbusServerThread:
    """Runs the pymodbus server for ``store`` in its own event loop thread."""

    def __init__(self, store: RegisterStore, transport: str = "tcp", host: str = "127.0.0.1",
                 baudrate: int = 115200, device_server: bool = False):
        self.store = store
        self.transport = transport
        self.host = host
        self.port = 0
        self.baudrate = baudrate
        self.link: PtyLink | DeviceServerLink | None = None
        if transport == "rtu":
            self.link = DeviceServerLink(baudrate) if device_server else PtyLink(baudrate)
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
        self._thread = threading.Thread(target=self._run, name=f"modbus-{self.transport}-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(5.0):
            raise RuntimeError("the simulated Modbus server did not start within 5 s")
        if self._error is not None:
            raise RuntimeError(f"the simulated Modbus server failed to start: {self._error}") from self._error
        if self.link:
            self.link.start((self.host, self.port))  # (a pty ignores the device's address)
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
        if self.transport == "tcp" or isinstance(self.link, DeviceServerLink):
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
