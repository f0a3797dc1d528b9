"""One session per robot: an exclusive lock in the robot's state folder.

Every command that can move the arm (run, baseline, calibrate, watch's runs, the Python API) holds it
from before it connects until it has let go of the controller. A second session on the same machine is
refused before it sends anything, with the holder named (pid, command, start time). The lock is an
OS lock (``flock``) on ``<state>/session.lock``: a holder that dies, even by SIGKILL or power loss,
releases it, and the next session takes it over and says whose it was. The file's text names the
holder for people and for ``doctor``; it is never what decides.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Callable, Iterator

from payload_agent.errors import RobotBusyError
from payload_agent.recording.state import RobotState

LOCK_NAME = "session.lock"


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or last held) a robot's session lock."""

    pid: int
    command: str
    started_utc: str
    host: str = ""

    def describe(self) -> str:
        where = f" on {self.host}" if self.host and self.host != socket.gethostname() else ""
        return f"pid {self.pid}{where}, `payload-agent {self.command}` since {self.started_utc}"

    def to_json(self) -> dict:
        return {"pid": self.pid, "command": self.command, "started_utc": self.started_utc, "host": self.host}


def lock_path(state: RobotState) -> Path:
    return state.root / LOCK_NAME


@contextlib.contextmanager
def robot_lock(state: RobotState, command: str, robot: str,
               out: Callable[[str], None] = lambda text: None) -> Iterator[LockHolder]:
    """Hold the robot's session lock for the block; RobotBusyError (exit 3) naming the holder if taken."""
    path = lock_path(state)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read(fd)
            who = holder.describe() if holder else "a session that has not yet written its name"
            raise RobotBusyError(f"robot {robot} is in use by another payload-agent session ({who}); "
                                 f"only one session may move a robot. Wait for it to finish, or stop it; "
                                 f"this session sent nothing to the controller (lock: {path})") from None
        stale = _read(fd)
        if stale is not None:
            gone = "that process is gone" if not _alive(stale.pid) else "that session no longer holds it"
            out(f"Took over the session lock of {robot} left by {stale.describe()}: {gone} "
                "(it ended without releasing the lock)")
        me = LockHolder(os.getpid(), command, datetime.now().astimezone().isoformat(timespec="seconds"),
                        socket.gethostname())
        _write(fd, json.dumps(me.to_json()))
        try:
            yield me
        finally:
            _write(fd, "")
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def current_holder(state: RobotState) -> LockHolder | None:
    """The live holder of the robot's lock, or None when no session holds it (for `doctor`)."""
    path = lock_path(state)
    if not path.exists():
        return None
    fd = os.open(path, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read(fd) or LockHolder(0, "(unknown)", "")
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _read(fd: int) -> LockHolder | None:
    os.lseek(fd, 0, os.SEEK_SET)
    text = os.read(fd, 4096).decode("utf-8", "replace").strip()
    if not text:
        return None
    try:
        data = json.loads(text)
        return LockHolder(int(data["pid"]), str(data["command"]), str(data["started_utc"]), str(data.get("host", "")))
    except (ValueError, KeyError, TypeError):
        return LockHolder(0, f"(unreadable lock text {text[:40]!r})", "")


def _write(fd: int, text: str) -> None:
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, text.encode("utf-8"))
    os.fsync(fd)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
