"""A minimal client of the UR dashboard server (TCP 29999): one request line, one reply line.

The Python ur-rtde wheel ships no dashboard client module, and the driver needs only a few
commands: identification (``PolyscopeVersion``, ``get robot model``, ``get serial number``),
``is in remote control``, and ``stop``. The dashboard is independent of RTDE and of the running
program, so a ``stop`` over a new dashboard connection is the driver's way to halt the arm when
its RTDE connections are gone (reply "Stopped": UR's dashboard server documentation).
"""

from __future__ import annotations

import re
import socket
import time
from dataclasses import dataclass

from payload_agent.errors import CommunicationError
from payload_agent.types import ControllerInfo

DASHBOARD_PORT = 29999


MAX_LINE_BYTES = 4096  # the dashboard's replies are short lines; anything longer is not one


def dashboard_query(host: str, *commands: str, timeout_s: float) -> list[str]:
    """Send each command on one new connection; their reply lines (CommunicationError on any failure).

    The whole exchange has one deadline (``timeout_s`` per reply line), and a reply line is at most
    ``MAX_LINE_BYTES``: a peer that trickles bytes or never sends a newline cannot hold the driver.
    """
    try:
        with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout_s) as s:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            reader = _LineReader(s, host, timeout_s * (1 + len(commands)))
            reader.line()  # greeting
            replies = []
            for cmd in commands:
                s.sendall(cmd.encode() + b"\n")
                replies.append(reader.line().decode(errors="replace").strip())
            return replies
    except OSError as exc:
        raise CommunicationError(f"cannot talk to the dashboard server at {host}:{DASHBOARD_PORT}: {exc}") from exc


class _LineReader:
    """Newline-terminated lines from a socket, bounded in length and by one deadline."""

    def __init__(self, sock: socket.socket, host: str, budget_s: float):
        self.sock, self.host = sock, host
        self.deadline = time.monotonic() + budget_s
        self.buf = b""

    def line(self) -> bytes:
        while b"\n" not in self.buf:
            if len(self.buf) > MAX_LINE_BYTES:
                raise CommunicationError(f"dashboard server {self.host}:{DASHBOARD_PORT} sent a reply line longer "
                                         f"than {MAX_LINE_BYTES} bytes")
            left = self.deadline - time.monotonic()
            try:
                if left <= 0:
                    raise TimeoutError
                self.sock.settimeout(left)
                chunk = self.sock.recv(1024)
            except TimeoutError:
                raise CommunicationError(f"dashboard server {self.host}:{DASHBOARD_PORT} did not complete its reply "
                                         "in time") from None
            if not chunk:
                raise CommunicationError(f"dashboard server {self.host}:{DASHBOARD_PORT} closed the connection")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return line


def dashboard_stop(host: str, timeout_s: float) -> bool:
    """Stop the running program (and so the arm) over a new dashboard connection; True on "Stopped"."""
    try:
        return dashboard_query(host, "stop", timeout_s=timeout_s)[0].startswith("Stopped")
    except CommunicationError:
        return False


@dataclass(frozen=True)
class Identity:
    info: ControllerInfo
    version: tuple[int, ...]  # PolyScope major, minor, bugfix, build
    remote: bool | None  # Remote Control (None: PolyScope before 5.6 cannot say)


def dashboard_identify(host: str, timeout_s: float) -> Identity:
    """Model, PolyScope version, serial number and Remote Control, as ur-rtde's own constructor asks them."""
    version_line, model = dashboard_query(host, "PolyscopeVersion", "get robot model", timeout_s=timeout_s)
    # ASCII digits, at most 9 each: a 5000-digit "version" is not one (int() would refuse it with ValueError)
    m = re.search(r"(?<![0-9])([0-9]{1,9})\.([0-9]{1,9})\.([0-9]{1,9})\.([0-9]{1,9})(?![0-9])", version_line)
    if not m:
        raise CommunicationError(f"unexpected PolyscopeVersion reply from {host}: {version_line!r}")
    version = tuple(int(x) for x in m.groups())
    serial, remote = "", None
    if version[0] == 5 and version[1] >= 6:
        serial, answer = dashboard_query(host, "get serial number", "is in remote control", timeout_s=timeout_s)
        remote = "true" in answer.lower()
        serial = serial if serial.isdigit() else ""
    suffix = "e" if version[0] >= 5 and not model.endswith("e") else ""
    info = ControllerInfo(vendor="Universal Robots", model=f"{model}{suffix}", firmware=m.group(0), serial=serial)
    return Identity(info, version, remote)
