"""JSON-RPC 2.0 over one TCP connection to the Elite EC control port (8055).

One request per line ending in "\\n"; the reply's ``result`` is a JSON-encoded string that
is decoded a second time (docs/sources.md, "Elite EC"). One call at a time per connection:
a lock serialises callers, so the supervision's watchdog thread may send ``stop`` on the
same connection as the thread that waits for a motion to end (it waits for the lock only
briefly and otherwise stops over a new connection). Replies are matched by id, so a late
reply to a call that timed out is skipped instead of answering the next call.
"""

from __future__ import annotations

import json
import select
import socket
import threading
import time
from typing import Any, Mapping

from payload_agent.errors import CommunicationError

# methods whose result may legitimately be a bare (not JSON-encoded) string on some firmware
_STRING_RESULT_METHODS = {"getSoftVersion"}
METHOD_NOT_FOUND = -32601
MAX_REPLY_BYTES = 1 << 20


class EliteRPCError(CommunicationError):
    """The controller answered a JSON-RPC error object."""

    def __init__(self, method: str, code: int, message: str):
        self.method = method
        self.code = code
        self.rpc_message = message
        super().__init__(f"Elite controller refused {method}: {message} (JSON-RPC error {code})")


class RpcClient:
    """Line-framed JSON-RPC 2.0 on one TCP connection; thread-safe (one call at a time)."""

    def __init__(self, host: str, port: int, connect_timeout_s: float, reply_timeout_s: float,
                 what: str = "JSON-RPC port"):
        self.host, self.port = host, port
        self.reply_timeout_s = reply_timeout_s
        self._lock = threading.Lock()
        self._next_id = 1
        self._buf = b""
        self._dead: str | None = None  # why the connection is unusable (closed, EOF, send failed)
        self.last_sent = False  # whether the current call's request went out (read under the lock only)
        self.unanswered = False  # the last call got no reply in time: the line is not to be trusted for a stop
        try:
            self._sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as e:
            raise CommunicationError(
                f"cannot connect to the Elite controller's {what} {host}:{port}: {e}. "
                "Check the robot's IP address, the network cable, and that the controller is powered on."
            ) from e
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    @property
    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    def close(self) -> None:
        self._dead = self._dead or "closed by the driver"
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        try:
            self._sock.close()
        except OSError:
            pass

    def alive(self) -> bool:
        """True unless the connection is known to be gone or mute: closed, failed, the peer's EOF is
        waiting, or the last call went unanswered.

        No round trip: a non-blocking peek sees an EOF (or reset) the controller sent while no
        call was reading.
        """
        if self._dead is not None or self.unanswered:
            return False
        try:
            # select first: a socket with a timeout would wait that long inside recv even with MSG_DONTWAIT
            readable, _, _ = select.select([self._sock], [], [], 0)
            if not readable:
                return True
            data = self._sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT)
        except (BlockingIOError, InterruptedError, socket.timeout):
            return True
        except (OSError, ValueError) as e:
            self._dead = f"connection error: {e}"
            return False
        if data == b"":
            self._dead = "the controller closed the connection"
            return False
        return True

    def call(self, method: str, params: Mapping[str, Any] | None = None, timeout_s: float | None = None,
             lock_timeout_s: float | None = None) -> Any:
        """One call; its decoded result. ``lock_timeout_s``: give up if another call holds the line that long."""
        timeout = self.reply_timeout_s if timeout_s is None else timeout_s
        if not self._lock.acquire(timeout=-1 if lock_timeout_s is None else lock_timeout_s):
            raise CommunicationError(f"the connection to {self.endpoint} stayed busy for {lock_timeout_s:g} s "
                                     f"({method} not sent)")
        try:
            return self._call_locked(method, params, timeout)
        finally:
            self._lock.release()

    def stop(self, timeout_s: float, lock_timeout_s: float | None = None) -> bool:
        """Send ``stop``; True if the controller answered true, False if it was sent but not acknowledged.

        Raises CommunicationError when it could not be sent (line busy, connection gone).
        """
        if not self._lock.acquire(timeout=-1 if lock_timeout_s is None else lock_timeout_s):
            raise CommunicationError(f"the connection to {self.endpoint} stayed busy for {lock_timeout_s:g} s "
                                     "(stop not sent)")
        try:
            return self._call_locked("stop", None, timeout_s) is True
        except CommunicationError:
            if self.last_sent:
                return False
            raise
        finally:
            self._lock.release()

    def _call_locked(self, method: str, params: Mapping[str, Any] | None, timeout: float) -> Any:
        if self._dead is not None:
            raise CommunicationError(f"the connection to {self.endpoint} is gone ({self._dead}); {method} not sent")
        self.last_sent = False
        req_id = self._next_id
        self._next_id += 1
        line = json.dumps({"jsonrpc": "2.0", "method": method, "params": dict(params or {}), "id": req_id},
                          separators=(",", ":")) + "\n"
        try:
            self._sock.settimeout(timeout)
            self._sock.sendall(line.encode("utf-8"))
        except OSError as e:
            self._dead = f"sending failed: {e}"
            raise CommunicationError(f"lost the connection to {self.endpoint} sending {method}: {e}") from e
        self.last_sent = True
        deadline = time.monotonic() + timeout
        while True:
            raw = self._read_line(method, deadline, timeout)
            try:
                reply = json.loads(raw.decode("utf-8"))
                if not isinstance(reply, dict):
                    raise ValueError("not a JSON object")
            except (UnicodeDecodeError, ValueError, RecursionError) as e:  # RecursionError: absurdly deep nesting
                raise CommunicationError(
                    f"unparseable reply to {method} from {self.endpoint}: {raw[:200]!r} ({e})") from e
            if reply.get("id") != req_id and reply.get("id") is not None:
                continue  # a late reply to an earlier request that timed out: skip it
            if "error" in reply:
                err = reply["error"] if isinstance(reply["error"], dict) else {}
                try:
                    code = int(err.get("code", 0) or 0)
                except (TypeError, ValueError, OverflowError):  # not a number: JSON-RPC says an integer
                    code = 0
                raise EliteRPCError(method, code, str(err.get("message", reply["error"])))
            if "result" not in reply:
                raise CommunicationError(
                    f"reply to {method} from {self.endpoint} has neither result nor error: {raw[:200]!r}")
            result = reply["result"]
            if not isinstance(result, str):
                return result  # tolerate a controller that does not double-encode
            try:
                return json.loads(result)
            except (ValueError, RecursionError) as e:
                if method in _STRING_RESULT_METHODS:
                    return result
                raise CommunicationError(
                    f"unparseable result of {method} from {self.endpoint}: {raw[:200]!r} ({e})") from e

    def _read_line(self, method: str, deadline: float, timeout: float) -> bytes:
        while b"\n" not in self._buf:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.unanswered = True
                raise CommunicationError(f"no reply to {method} from {self.endpoint} within {timeout:g} s")
            self._sock.settimeout(remaining)
            try:
                chunk = self._sock.recv(65536)
            except socket.timeout:
                continue
            except OSError as e:
                self._dead = f"connection error: {e}"
                raise CommunicationError(f"lost the connection to {self.endpoint} waiting for {method}: {e}") from e
            if not chunk:
                self._dead = "the controller closed the connection"
                raise CommunicationError(f"the controller {self.endpoint} closed the connection during {method}")
            self._buf += chunk
            if len(self._buf) > MAX_REPLY_BYTES:
                raise CommunicationError(f"reply to {method} exceeds 1 MiB without a newline: {self._buf[:200]!r}")
        line, self._buf = self._buf.split(b"\n", 1)
        self.unanswered = False
        return line.strip()


def stop_over_new_connection(host: str, port: int, connect_timeout_s: float, reply_timeout_s: float) -> bool:
    """Open a new 8055 connection, send ``stop``, close it; True if the controller answered true.

    False when the request went out but no (true) answer came; CommunicationError when it could
    not be sent at all (no connection).
    """
    client = RpcClient(host, port, connect_timeout_s, reply_timeout_s)
    try:
        return client.stop(reply_timeout_s)
    finally:
        client.close()
