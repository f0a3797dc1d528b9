"""The UR dashboard client cannot be held by a peer: an endless reply line and a trickling one both end in
CommunicationError within the exchange's deadline, and a well-formed exchange still works."""

from __future__ import annotations

import time

import pytest

from loopback import LoopbackServer, listen_on_own_address
from payload_agent.drivers.ur_rtde.dashboard import DASHBOARD_PORT, MAX_LINE_BYTES, dashboard_query
from payload_agent.errors import CommunicationError


class Peer(LoopbackServer):
    """A loopback server on port 29999 of its own 127.x address, serving each connection with ``behave``."""

    def __init__(self, behave):
        ls, host = listen_on_own_address(DASHBOARD_PORT)
        super().__init__(ls, host, lambda conn: behave(conn, self.stop))


def _endless(conn, stop):
    while not stop.is_set():
        conn.sendall(b"x" * 1024)


def _trickle(conn, stop):
    conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
    while not stop.is_set():
        conn.sendall(b"y")
        time.sleep(0.05)


def _polite(conn, stop):
    conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
    with conn.makefile("rb") as f:
        while f.readline():
            conn.sendall(b"Stopped\n")


@pytest.mark.parametrize("behave, said", [(_endless, f"longer than {MAX_LINE_BYTES} bytes"),
                                          (_trickle, "did not complete its reply in time")])
def test_a_peer_cannot_hold_the_client(behave, said):
    peer = Peer(behave)
    try:
        t0 = time.monotonic()
        with pytest.raises(CommunicationError, match=said):
            dashboard_query(peer.host, "stop", timeout_s=0.5)
        assert time.monotonic() - t0 < 30.0  # bounded by the deadline (1 s here), not by the peer
    finally:
        peer.close()


def test_a_well_formed_exchange_still_works():
    peer = Peer(_polite)
    try:
        assert dashboard_query(peer.host, "stop", "stop", timeout_s=2.0) == ["Stopped", "Stopped"]
    finally:
        peer.close()
