"""Line-framed JSON-RPC 2.0 server, as on the Elite EC control port (TCP 8055).

Framing and envelope as the real controller and Elite's own clients use them
(Elite EC SDK socket manual; Elite's python library JunJie-zhang-o/eliterobot
``elite/_baseec.py``; docs.elibot.cn "EC机器人8055端口使用": "注意字符串最后需要换行",
the request must end with a newline):

    -> {"jsonrpc":"2.0","method":"getRobotMode","params":{},"id":1}\\n
    <- {"jsonrpc":"2.0","result":"2","id":1}\\n

* one request per line; bytes without a terminating "\\n" are buffered and get no
  answer until the newline arrives; several requests in one TCP chunk are answered
  in order;
* ``result`` is always a JSON-encoded *string* ("true", "2", "[0.0, ...]"), which the
  clients decode a second time (``json.loads(jdata["result"])``);
* errors are JSON-RPC error objects: -32700 parse error, -32600 invalid request,
  -32601 method not found, -32602 invalid params; others are application errors.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from typing import Any, Callable

from payload_agent.fakes.tcp_server import TCPServer, read_lines, shutdown_socket

PARSE_ERROR = -32700
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
SERVER_ERROR = -32000  # implementation-defined (JSON-RPC reserves -32000..-32099)

MAX_LINE = 1 << 20


class RpcError(Exception):
    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


Handler = Callable[[str, Any], Any]  # (method, params) -> python value to JSON-encode


class LineJsonRpcServer:
    """TCP server (``fakes.tcp_server``); ``handler(method, params)`` returns a value or raises RpcError."""

    def __init__(self, host: str, port: int, handler: Handler, name: str = "elite-rpc",
                 raw_override: Callable[[str], str | None] | None = None):
        self._handler = handler
        self._raw_override = raw_override  # test hook: answer a method with a raw (broken) line
        self._server = TCPServer(host, port, self._serve, name=name)
        self.port = self._server.port
        self._socks: set[socket.socket] = set()
        self._socks_lock = threading.Lock()
        # faults (set by the controller): every reply held back this long; connections whose requests are swallowed
        self.reply_delay_s = 0.0
        self._hung: set[socket.socket] = set()

    def start(self) -> None:
        self._server.start()

    def _serve(self, sock: socket.socket, addr) -> None:
        with self._socks_lock:
            self._socks.add(sock)
        try:
            # a line that never ends (longer than MAX_LINE) drops the client
            for line in read_lines(sock, lambda: self._server.closing, max_line=MAX_LINE):
                if sock in self._hung:
                    continue
                reply = self._handle_line(line)  # executed now; with a delay, only the answer comes late
                if reply is not None:
                    delay = self.reply_delay_s
                    if delay > 0:
                        time.sleep(delay)
                    sock.sendall(reply)
        finally:
            with self._socks_lock:
                self._socks.discard(sock)
                self._hung.discard(sock)

    @property
    def connection_count(self) -> int:
        with self._socks_lock:
            return len(self._socks)

    def hang_connections(self) -> None:
        """Every connection open now swallows its requests from here on (a hung session); new ones are served."""
        with self._socks_lock:
            self._hung = set(self._socks)

    def unhang_connections(self) -> None:
        with self._socks_lock:
            self._hung = set()

    def drop_connections(self) -> None:
        """Close every client connection (the port keeps listening, as after a controller-side reset)."""
        with self._socks_lock:
            socks = list(self._socks)
        for sock in socks:
            shutdown_socket(sock)

    def _handle_line(self, line: bytes) -> bytes | None:
        text = line.strip()
        if not text:
            return None
        try:
            req = json.loads(text.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            return _encode({"jsonrpc": "2.0", "error": {"code": PARSE_ERROR, "message": "Parse error"}, "id": None})
        if not isinstance(req, dict):
            return _encode({"jsonrpc": "2.0", "error": {"code": INVALID_REQUEST, "message": "Invalid Request"},
                            "id": None})
        req_id = req.get("id")
        method = req.get("method")
        if req.get("jsonrpc") != "2.0" or not isinstance(method, str):
            return _encode({"jsonrpc": "2.0", "error": {"code": INVALID_REQUEST, "message": "Invalid Request"},
                            "id": req_id})
        if self._raw_override is not None:
            raw = self._raw_override(method)
            if raw is not None:
                return (raw + "\n").encode("utf-8")
        if "id" not in req:
            # a notification: executed, never answered (JSON-RPC 2.0 §4.1)
            try:
                self._handler(method, req.get("params"))
            except Exception:
                pass
            return None
        try:
            value = self._handler(method, req.get("params"))
            return _encode({"jsonrpc": "2.0", "result": json.dumps(value), "id": req_id})
        except RpcError as e:
            return _encode({"jsonrpc": "2.0", "error": {"code": e.code, "message": e.message}, "id": req_id})
        except Exception as e:  # a bug in the fake: still answer like a server would
            return _encode({"jsonrpc": "2.0", "error": {"code": INTERNAL_ERROR, "message": f"Internal error: {e}"},
                            "id": req_id})

    def close(self) -> None:
        self._server.close()


def _encode(obj: dict) -> bytes:
    return (json.dumps(obj, separators=(",", ":")) + "\n").encode("utf-8")
