"""A listening socket on a fixed port of a loopback address of its own (127.x.y.z), for clients whose port
cannot be chosen (UR's dashboard is always 29999): tests never collide with each other or a simulation."""

from __future__ import annotations

import random
import socket

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
