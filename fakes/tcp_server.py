"""The loopback TCP server every fake controller port is built on.

One listening socket on ``host:port`` (port 0 = an ephemeral port, read back from
``.port``), an accept thread, and one thread per accepted connection that runs
``handler(conn, addr)``. The protocol lives entirely in the handler; this module only
owns sockets and threads, so every fake port opens, serves and shuts down the same way:

* ``start()`` starts accepting; ``close()`` stops accepting, shuts every open
  connection down (which wakes a handler blocked in ``recv`` or ``sendall``) and
  joins the threads, so nothing keeps a port or a thread after ``close()`` returns;
* a handler returning or raising ``OSError`` (the peer went away) ends its connection
  quietly; any other exception is a bug in the fake and is reported through
  ``on_error`` (default: kept in ``errors``) rather than lost with the thread;
* accepted sockets are blocking, with TCP_NODELAY (controllers answer small requests
  at once; Nagle would add 40 ms delays to the request/reply protocols).

Handlers that need to stop early on ``close()`` can check ``server.closing``.
"""

from __future__ import annotations

import socket
import threading
from typing import Callable, Iterator

from payload_agent.fakes.base import require_loopback

Handler = Callable[[socket.socket, tuple], None]

ACCEPT_POLL_S = 0.2  # the accept loop re-checks `closing` this often (portable wake-up)


class TCPServer:
    """Listening socket + accept thread + one handler thread per connection."""

    def __init__(self, host: str, port: int, handler: Handler, *, name: str = "fake-tcp", backlog: int = 8,
                 on_error: Callable[[str], None] | None = None):
        self.host = host
        self.name = name
        self._handler = handler
        self._on_error = on_error
        self.errors: list[str] = []
        require_loopback(host)
        ls = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a restarted fake may rebind at once
        try:
            ls.bind((host, port))
            ls.listen(backlog)
        except OSError as exc:
            ls.close()
            raise OSError(exc.errno, f"{name}: cannot listen on {host}:{port}: {exc.strerror or exc}") from exc
        ls.settimeout(ACCEPT_POLL_S)
        self._listener = ls
        self.port: int = ls.getsockname()[1]
        self._closing = threading.Event()
        self._lock = threading.Lock()
        self._conns: dict[socket.socket, threading.Thread] = {}
        self._accept_thread = threading.Thread(target=self._accept_loop, name=f"{name}-accept-{self.port}",
                                               daemon=True)
        self._started = False

    @property
    def closing(self) -> bool:
        return self._closing.is_set()

    @property
    def connection_count(self) -> int:
        with self._lock:
            return len(self._conns)

    def start(self) -> "TCPServer":
        if not self._started:
            self._started = True
            self._accept_thread.start()
        return self

    def _accept_loop(self) -> None:
        while not self._closing.is_set():
            try:
                conn, addr = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:  # listener closed
                return
            conn.settimeout(None)
            try:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass
            th = threading.Thread(target=self._run_conn, args=(conn, addr), daemon=True,
                                  name=f"{self.name}-conn-{self.port}")
            with self._lock:
                if self._closing.is_set():
                    _shutdown(conn)
                    return
                self._conns[conn] = th
            th.start()

    def _run_conn(self, conn: socket.socket, addr: tuple) -> None:
        try:
            self._handler(conn, addr)
        except OSError:  # includes ConnectionError: the peer or close() ended the connection
            pass
        except Exception as exc:  # a bug in the fake's handler: make it visible
            text = f"{self.name} {self.host}:{self.port}: handler failed: {exc!r}"
            self.errors.append(text)
            if self._on_error is not None:
                self._on_error(text)
        finally:
            with self._lock:
                self._conns.pop(conn, None)
            _shutdown(conn)

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop accepting, end every connection, join the threads. Idempotent; never raises."""
        self._closing.set()
        try:
            self._listener.close()
        except OSError:
            pass
        if self._accept_thread.is_alive() and self._accept_thread is not threading.current_thread():
            self._accept_thread.join(timeout=timeout_s)
        with self._lock:
            conns = dict(self._conns)
        for conn in conns:
            _shutdown(conn)
        for th in conns.values():
            if th.is_alive() and th is not threading.current_thread():
                th.join(timeout=timeout_s)


def read_lines(sock: socket.socket, closing: Callable[[], bool], bufsize: int = 65536,
               max_line: int | None = None) -> Iterator[bytes]:
    """The newline-terminated lines a peer sends (without the newline), until it closes, ``closing()``,
    or an unfinished line grows beyond ``max_line`` bytes.

    Both newline-framed protocols the fakes serve (Elite JSON-RPC, UR dashboard) read this way:
    a line may arrive in pieces, several may arrive in one chunk.
    """
    buf = b""
    while not closing():
        chunk = sock.recv(bufsize)
        if not chunk:
            return
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            yield line
        if max_line is not None and len(buf) > max_line:
            return


def _shutdown(s: socket.socket) -> None:
    """Shut a socket down both ways (wakes threads blocked on it), then close it."""
    try:
        s.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    try:
        s.close()
    except OSError:
        pass


shutdown_socket = _shutdown
