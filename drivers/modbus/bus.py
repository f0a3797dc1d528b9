"""One Modbus connection (TCP socket or RTU serial line) through pymodbus' synchronous clients.

It reads ``Block``s and writes entries, and turns every way a request can fail into a
``CommunicationError`` that names the request: an exception reply (with the Modbus exception
code and its name), no reply within the timeout, or a connection the device closed.
pymodbus is pinned (3.16.1): its client API changed between 3.x minors.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Sequence

from payload_agent.drivers.modbus.options import Endpoint
from payload_agent.drivers.modbus.registers import Block, Entry, group_writes
from payload_agent.errors import CommunicationError, ConfigError

try:
    from pymodbus import FramerType
    from pymodbus.client import ModbusSerialClient, ModbusTcpClient
    from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
except ImportError as _exc:  # only this driver needs it
    raise ConfigError("driver.type", "the modbus driver needs pymodbus 3.16.1 and pyserial: "
                                     f"pip install 'payload-agent[modbus]' (import failed: {_exc})") from _exc

_FUNCTION_CODES = {"read_coils": 1, "read_discrete_inputs": 2, "read_holding_registers": 3,
                   "read_input_registers": 4, "write_coil": 5, "write_register": 6, "write_coils": 15,
                   "write_registers": 16}
# pymodbus logs every timeout and stale reply with a hex dump of the last frames to stderr; the driver
# reports each failure itself, in words, so the library's own log is kept to critical messages.
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

# Modbus application protocol v1.1b, section 7
EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "server device failure", 5: "acknowledge", 6: "server device busy",
                   8: "memory parity error", 10: "gateway path unavailable",
                   11: "gateway target device failed to respond"}


class ModbusReplyError(CommunicationError):
    """The device answered with a Modbus exception."""

    def __init__(self, message: str, code: int):
        self.code = code
        super().__init__(message)


class ModbusTimeout(CommunicationError):
    """No reply within the timeout (the request may or may not have reached the device)."""


class StaleReply(ModbusTimeout):
    """A reply that does not answer the request: a late reply to an earlier one (RTU has no transaction id)."""


class ConnectionLost(CommunicationError):
    """The connection is closed or could not be opened."""


class ModbusBus:
    """One client connection; thread-safe (one request at a time)."""

    def __init__(self, endpoint: Endpoint, role: str = "connection"):
        self.endpoint = endpoint
        self.role = role
        self._lock = threading.RLock()
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._lost: str | None = None
        # a request timed out and its reply may still arrive: RTU drains the line before the next request, TCP
        # opens a new connection (pymodbus' sync client can take a late reply on the old one for the next request's:
        # a status read answered with another 5-register block's words read as an emergency stop)
        self._stale = False

    # -- connection ---------------------------------------------------------------------------
    def open(self) -> None:
        with self._lock:
            self._client = self._connected_client()
            self._lost = None

    def _connected_client(self) -> ModbusTcpClient | ModbusSerialClient:
        ep = self.endpoint
        if ep.transport == "tcp":
            client = ModbusTcpClient(ep.host, port=ep.port, timeout=ep.timeout_s, retries=ep.retries,
                                     reconnect_delay=0, reconnect_delay_max=0)
        elif ep.device_server:  # RTU frames over the device server's TCP connection, as on the line
            host, port = ep.device_server
            client = ModbusTcpClient(host, port=port, framer=FramerType.RTU, timeout=ep.timeout_s,
                                     retries=ep.retries, reconnect_delay=0, reconnect_delay_max=0)
        else:
            client = ModbusSerialClient(ep.serial_port, framer=FramerType.RTU, baudrate=ep.baudrate,
                                        parity=ep.parity, stopbits=ep.stopbits, bytesize=ep.bytesize,
                                        timeout=ep.timeout_s, retries=ep.retries, reconnect_delay=0,
                                        reconnect_delay_max=0)
        error = None
        try:
            ok = client.connect()
        except Exception as exc:  # pyserial raises for a missing device
            ok, error = False, str(exc)
        if not ok:
            client.close()
            raise ConnectionLost(f"cannot open the Modbus {self.role} to {ep.describe()}" + (f": {error}" if error else ""))
        return client

    def close(self) -> None:
        with self._lock:
            client, self._client = self._client, None
        if client is not None:
            try:
                client.close()
            except Exception:
                pass

    @property
    def alive(self) -> bool:
        """Open and not known to be broken (no round trip)."""
        client = self._client
        return client is not None and self._lost is None and bool(client.connected)

    # -- requests -----------------------------------------------------------------------------
    def read(self, block: Block) -> list[int] | list[bool]:
        """The words of ``block``; CommunicationError naming the block on any failure."""
        what = f"read of {block.describe()} ({', '.join(e.name for e in block.entries)})"
        fn = {"holding": "read_holding_registers", "input": "read_input_registers", "coil": "read_coils",
              "discrete_input": "read_discrete_inputs"}[block.table]
        try:
            return self._read_once(block, what, fn)
        except StaleReply:  # RTU: the late answer to an earlier request was in the way (drained before the
            return self._read_once(block, what, fn)  # next request); a read changes nothing, so ask it once more

    def _read_once(self, block: Block, what: str, fn: str) -> list[int] | list[bool]:
        resp = self._execute(what, fn, block.address, count=block.count, device_id=self.endpoint.device_id)
        if block.table in ("coil", "discrete_input"):
            words = list(resp.bits)
            ok = block.count <= len(words) < block.count + 8
            words = words[:block.count]
        else:
            words = list(resp.registers)
            ok = len(words) == block.count
        if not ok:
            self._mismatch(f"the {what} was answered with {len(words)} values")
        return words

    def _mismatch(self, text: str) -> None:
        if self.endpoint.transport == "rtu":  # most likely the late reply to a request that timed out
            self._stale = True
            raise StaleReply(f"{text}: a late reply to an earlier request, discarded")
        raise CommunicationError(f"{text}: the device does not answer what was asked")

    def write(self, entries: Sequence[tuple[Entry, Sequence[float]]], wait_s: float | None = None) -> None:
        """Encode and write entries; adjacent ones share a request, in address order.

        ``wait_s``: how long to wait for a request already under way on this connection (None: as long as
        it takes); ModbusTimeout if it is still busy then (a stop must not queue behind an unanswered read).
        """
        words = {e.name: e.encode(v) for e, v in entries}
        for block in group_writes([e for e, _ in entries]):
            data: list = []
            for e in block.entries:
                data.extend(words[e.name])
            what = f"write of {block.describe()} ({', '.join(e.name for e in block.entries)})"
            dev = self.endpoint.device_id
            if block.table == "coil":
                if len(data) == 1:
                    self._execute(what, "write_coil", block.address, bool(data[0]), device_id=dev, wait_s=wait_s)
                else:
                    self._execute(what, "write_coils", block.address, [bool(b) for b in data], device_id=dev,
                                  wait_s=wait_s)
            elif len(data) == 1:
                self._execute(what, "write_register", block.address, int(data[0]), device_id=dev, wait_s=wait_s)
            else:
                self._execute(what, "write_registers", block.address, [int(w) for w in data], device_id=dev,
                              wait_s=wait_s)

    def _reconnect(self, what: str):
        """A new TCP connection in place of one that may still deliver a late reply (the old one is closed only
        once the new one is open: the connection never looks lost to the supervision meanwhile)."""
        try:
            client = self._connected_client()
        except ConnectionLost as exc:
            self._lost = str(exc)
            raise ConnectionLost(f"the {what} could not go out: reconnecting after a late reply failed ({exc})") from None
        old, self._client, self._stale = self._client, client, False
        try:
            old.close()
        except Exception:
            pass
        return client

    def _drain(self, client) -> None:
        """Wait out the line's silence and throw away whatever arrived (RTU after a timeout)."""
        line = getattr(client, "socket", None)  # a serial port, or the device server's TCP socket
        try:
            time.sleep(max(0.005, 35.0 / self.endpoint.baudrate))  # 3.5 characters and then some
            if hasattr(line, "reset_input_buffer"):
                line.reset_input_buffer()
            elif line is not None:
                line.setblocking(False)
                while line.recv(4096):
                    pass
        except Exception:  # nothing (more) to read: BlockingIOError
            pass
        self._stale = False

    def _execute(self, what: str, fn: str, *args, wait_s: float | None = None, **kwargs):
        if not self._lock.acquire(timeout=-1 if wait_s is None else wait_s):
            raise ModbusTimeout(f"the {what} could not go out: the {self.role} is waiting for another reply")
        try:
            return self._execute_locked(what, fn, *args, **kwargs)
        finally:
            self._lock.release()

    def _execute_locked(self, what: str, fn: str, *args, **kwargs):
        client = self._client
        if client is None:
            raise ConnectionLost(f"the Modbus {self.role} to {self.endpoint.describe()} is closed ({what})")
        if self._stale:
            if self.endpoint.transport == "rtu":
                self._drain(client)
            else:
                client = self._reconnect(what)
        try:
            resp = getattr(client, fn)(*args, **kwargs)
        except ConnectionException as exc:
            self._lost = str(exc)
            raise ConnectionLost(f"the {what} failed: the connection to {self.endpoint.describe()} "
                                 f"is lost ({exc})") from None
        except ModbusIOException as exc:
            if not client.connected:
                self._lost = str(exc)
                raise ConnectionLost(f"the {what} failed: {self.endpoint.describe()} stopped answering "
                                     f"and the connection was closed") from None
            self._stale = True
            raise ModbusTimeout(f"no reply to the {what} from {self.endpoint.describe()} within "
                                f"{self.endpoint.timeout_s:g} s") from None
        except (ModbusException, OSError, ValueError) as exc:
            self._lost = str(exc)
            raise ConnectionLost(f"the {what} failed: {type(exc).__name__}: {exc}") from None
        if resp is None:
            raise ModbusTimeout(f"no reply to the {what}")
        if (resp.function_code & 0x7F) != _FUNCTION_CODES[fn]:
            self._mismatch(f"the {what} was answered with function code {resp.function_code}")
        if resp.isError():
            code = int(getattr(resp, "exception_code", 0) or 0)
            name = EXCEPTION_NAMES.get(code, "unknown exception")
            raise ModbusReplyError(f"{self.endpoint.describe()} answered the {what} with Modbus exception "
                                   f"{code} ({name})", code)
        return resp
