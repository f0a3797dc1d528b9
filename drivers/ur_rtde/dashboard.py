"""A minimal client of the UR dashboard server (TCP 29999): one request line, one reply line.

The Python ur-rtde wheel ships no dashboard client module, and the driver needs only a few
commands: identification (``PolyscopeVersion``, ``get robot model``, ``get serial number``),
``is in remote control``, and ``stop``. The dashboard is independent of RTDE and of the running
program, so a ``stop`` over a new dashboard connection is the driver's way to halt the arm when
its RTDE connections are gone (reply "Stopped": UR's dashboard server documentation).
"""

from __future__ import annotations

import socket

from payload_agent.errors import CommunicationError

DASHBOARD_PORT = 29999


def dashboard_query(host: str, *commands: str, timeout_s: float) -> list[str]:
    """Send each command on one new connection; their reply lines (CommunicationError on any failure)."""
    try:
        with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout_s) as s:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            f = s.makefile("rwb")
            f.readline()  # greeting
            replies = []
            for cmd in commands:
                f.write(cmd.encode() + b"\n")
                f.flush()
                line = f.readline()
                if not line:
                    raise CommunicationError(f"dashboard server {host}:{DASHBOARD_PORT} closed the connection")
                replies.append(line.decode(errors="replace").strip())
            return replies
    except OSError as exc:
        raise CommunicationError(f"cannot talk to the dashboard server at {host}:{DASHBOARD_PORT}: {exc}") from exc


def dashboard_stop(host: str, timeout_s: float) -> bool:
    """Stop the running program (and so the arm) over a new dashboard connection; True on "Stopped"."""
    try:
        return dashboard_query(host, "stop", timeout_s=timeout_s)[0].startswith("Stopped")
    except CommunicationError:
        return False
