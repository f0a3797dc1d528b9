"""A listening socket on a fixed port of a loopback address of its own (127.x.y.z), for clients whose port
cannot be chosen (UR's dashboard is always 29999): tests never collide with each other or a simulation."""

from __future__ import annotations

import random
import socket
import threading

import pytest


def listen_on_own_address(port: int) -> tuple[socket.socket, str]:
    """(listening socket, its 127.x.y.z host); skips the test if no such address is free."""
    rng = random.Random()
    for _ in range(50):
        host = f"127.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
        try:
            return socket.create_server((host, port)), host
        except OSError:
            continue
    pytest.skip(f"no free loopback address for port {port}")


class LoopbackServer:
    """Accepts connections on ``ls`` until closed; each is served by ``handle(conn)`` on a thread of its own
    (OSError from a connection ends just that connection)."""

    def __init__(self, ls: socket.socket, host: str, handle):
        self.ls, self.host, self.handle = ls, host, handle
        self.stop = threading.Event()
        ls.settimeout(0.2)
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.ls.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            try:
                self.handle(conn)
            except OSError:
                pass

    def close(self) -> None:
        self.stop.set()
        self.ls.close()
