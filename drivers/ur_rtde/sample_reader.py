"""``RTDESampleReader``: every data package of the sample recipe, in the controller's order, from an RTDE
connection of the driver's own.

Why not ur_rtde's receive interface: ``RTDEReceiveInterface`` keeps only the newest package, and its getters
are polled from Python; a package that arrives while the Python reader waits for the GIL or for a core is
replaced before it is read. On a loaded host that lost a third of a 500 Hz stream (docs/benchmarks.md,
session 14), and ur_rtde's own ``startFileRecording`` is no cure: its recorder thread copies the newest state
once per period on a timer of its own, so it duplicates and skips packages just the same (measured there). A
TCP connection keeps every package the controller sent until it is read, so a reader that reads the socket
package by package loses none; it only reads some of them late (their receive time says when).

The protocol is UR's RTDE, version 2 (UR's "Real-Time Data Exchange (RTDE) Guide"; docs/sources.md): a
package is a big-endian uint16 size (header included), a uint8 type and the payload. The reader requests
protocol 2, sets up one output recipe (frequency as a double, then the field names), checks the types the
controller answers, starts the synchronisation and reads data packages (type 'U': the recipe id, then the
fields). The controller drops a client that does not read (ur_client_library's RTDE client notes the same),
and this one reads from the driver's stream thread from connect to close.

Anything that is not a well-formed data package of our recipe ends the stream (CommunicationError): a
package with a size that cannot be, a data package of the wrong length or recipe, an error message from the
controller, or the connection closing.
"""

from __future__ import annotations

import socket
import struct
import time
from typing import Sequence

from payload_agent.errors import CommunicationError

HEADER = struct.Struct(">HB")
REQUEST_PROTOCOL_VERSION, TEXT_MESSAGE, DATA_PACKAGE = 86, 77, 85
SETUP_OUTPUTS, START, PAUSE = 79, 83, 80
PROTOCOL_VERSION = 2
MSG_ERROR_LEVEL = 1  # text message severities: 0 exception, 1 error, 2 warning, 3 info
FIELD_SIZES = {"DOUBLE": 1, "VECTOR6D": 6, "VECTOR3D": 3, "UINT64": 1, "UINT32": 1, "INT32": 1}
FIELD_FORMATS = {"DOUBLE": "d", "VECTOR6D": "6d", "VECTOR3D": "3d", "UINT64": "Q", "UINT32": "I", "INT32": "i"}
MAX_PACKAGE = 4096  # no recipe of ours comes near; a larger size is a broken stream
RECV_BYTES = 1 << 16


class RTDESampleReader:
    """One RTDE output recipe, read package by package (``read``); ``fields`` name → expected RTDE type."""

    def __init__(self, host: str, port: int, frequency_hz: float, fields: Sequence[tuple[str, str]]):
        self.host, self.port, self.frequency_hz = host, port, float(frequency_hz)
        self.names = [n for n, _ in fields]
        self.types = [t for _, t in fields]
        self._struct = struct.Struct(">B" + "".join(FIELD_FORMATS[t] for t in self.types))
        self._sock: socket.socket | None = None
        self._buf = bytearray()
        self._rid = 0
        self.lost = False  # the connection failed or the controller closed it: the link is likely gone

    def describe(self) -> str:
        return f"{self.host}:{self.port}"

    # -- set-up ----------------------------------------------------------------------------------
    def open(self, timeout_s: float) -> None:
        """Connect, request protocol 2, set up the recipe and start; CommunicationError naming what failed."""
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=timeout_s)
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as exc:
            raise CommunicationError(f"cannot open the RTDE sample connection to {self.describe()}: {exc}") from exc
        deadline = time.monotonic() + timeout_s
        reply = self._request(REQUEST_PROTOCOL_VERSION, struct.pack(">H", PROTOCOL_VERSION), deadline)
        if reply[:1] != b"\x01":
            raise CommunicationError(f"the UR controller at {self.describe()} refused RTDE protocol version "
                                     f"{PROTOCOL_VERSION} (reply {reply.hex()})")
        reply = self._request(SETUP_OUTPUTS, struct.pack(">d", self.frequency_hz) + ",".join(self.names).encode(),
                              deadline)
        got = reply[1:].decode(errors="replace").split(",")
        if not reply[:1] or reply[0] == 0 or got != self.types:
            bad = [f"{n} ({g})" for n, t, g in zip(self.names, self.types, got + [""] * len(self.names)) if g != t]
            raise CommunicationError(f"the UR controller at {self.describe()} refused the RTDE sample recipe at "
                                     f"{self.frequency_hz:g} Hz: {', '.join(bad) or reply.hex()} (expected types "
                                     f"{', '.join(self.types)})")
        self._rid = reply[0]
        if self._request(START, b"", deadline)[:1] != b"\x01":
            raise CommunicationError(f"the UR controller at {self.describe()} did not start the RTDE sample stream")

    def _request(self, kind: int, payload: bytes, deadline: float) -> bytes:
        """Send one set-up package and return the payload of its reply (data packages before it are dropped:
        none is ours before START)."""
        try:
            self._sock.sendall(HEADER.pack(HEADER.size + len(payload), kind) + payload)
        except OSError as exc:
            raise CommunicationError(f"lost the RTDE sample connection to {self.describe()}: {exc}") from exc
        while True:
            got = self._next_package(deadline)
            if got is None:
                raise CommunicationError(f"the UR controller at {self.describe()} did not answer RTDE request "
                                         f"{chr(kind)!r} in time")
            if got[0] == kind:
                return got[1]
            if got[0] == TEXT_MESSAGE:
                self._text(got[1])

    # -- streaming -------------------------------------------------------------------------------
    def read(self, timeout_s: float) -> tuple | None:
        """The next data package's fields (in recipe order; vectors as tuples), or None if none came in time."""
        got = self._next_package(time.monotonic() + timeout_s)
        while got is not None and got[0] == TEXT_MESSAGE:
            self._text(got[1])  # warnings and infos are skipped, errors raise
            got = self._next_package(time.monotonic() + timeout_s)
        if got is None:
            return None
        kind, payload = got
        if kind != DATA_PACKAGE or len(payload) != self._struct.size or payload[0] != self._rid:
            raise CommunicationError(
                f"the RTDE sample stream from {self.describe()} sent a package of type {kind} with {len(payload)} "
                f"bytes (recipe {payload[:1].hex() or '-'}), not a {self._struct.size}-byte data package of recipe "
                f"{self._rid}: the data is corrupt")
        flat = self._struct.unpack(payload)[1:]
        out, i = [], 0
        for t in self.types:
            n = FIELD_SIZES[t]
            out.append(flat[i] if n == 1 else tuple(flat[i:i + n]))
            i += n
        return tuple(out)

    def _text(self, payload: bytes) -> None:
        """A text message (protocol 2: level, then the message and its source, each a length-prefixed string)."""
        if not payload:
            return
        level = payload[-1]
        try:
            n = payload[0]
            text = payload[1:1 + n].decode(errors="replace")
        except IndexError:
            text = payload.decode(errors="replace")
        if level <= MSG_ERROR_LEVEL:
            raise CommunicationError(f"the UR controller at {self.describe()} ended the RTDE sample stream: {text}")

    def _next_package(self, deadline: float) -> tuple[int, bytes] | None:
        """The next whole package (type, payload) from the buffer or the socket; None when ``deadline`` passes."""
        while True:
            if len(self._buf) >= HEADER.size:
                size, kind = HEADER.unpack_from(self._buf)
                if size < HEADER.size or size > MAX_PACKAGE:
                    raise CommunicationError(f"the RTDE sample stream from {self.describe()} framed a package of "
                                             f"{size} bytes: the data is corrupt")
                if len(self._buf) >= size:
                    payload = bytes(self._buf[HEADER.size:size])
                    del self._buf[:size]
                    return kind, payload
            if not self._fill(deadline):
                return None

    def _fill(self, deadline: float) -> bool:
        sock = self._sock
        if sock is None:
            raise CommunicationError(f"the RTDE sample connection to {self.describe()} is closed")
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        try:
            sock.settimeout(remaining)
            chunk = sock.recv(RECV_BYTES)
        except (socket.timeout, BlockingIOError):
            return False
        except OSError as exc:
            self.lost = True
            raise CommunicationError(f"lost the RTDE sample connection to {self.describe()}: {exc}") from exc
        if not chunk:
            self.lost = True
            raise CommunicationError(f"lost the RTDE sample connection to {self.describe()}: the controller closed it")
        self._buf += chunk
        return True

    def close(self) -> None:
        """Pause the synchronisation (best effort) and close. Never raises."""
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.settimeout(0.2)
            sock.sendall(HEADER.pack(HEADER.size, PAUSE))
        except OSError:
            pass
        try:
            sock.close()
        except OSError:
            pass
