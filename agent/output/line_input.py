"""One line from the operator's terminal that a signal can always interrupt.

A plain ``readline()`` blocks in one ``read`` system call. When SIGTERM or Ctrl-C is delivered to
one of the session's other threads (a driver's receive thread, a client library's thread), that
call is never interrupted, and Python runs its handler only in the main thread once the call
returns: the operator's Ctrl-C at a question would then do nothing until they pressed Enter (seen
in CI: a SIGTERM at the prompt left the process waiting for a minute). Waiting in short ``select``
slices lets the main thread run the handler within a fraction of a second, whatever thread the
kernel chose. The file descriptor is read a byte at a time, so no later line waits unseen in a
buffer behind the next ``select``.
"""

from __future__ import annotations

import io
import os
import select
import sys
from typing import TextIO

POLL_S = 0.2  # how late a signal's handler may run at most while the operator is being asked


def read_line(stream: TextIO) -> str:
    """The next line with its newline ("" at end of input), as ``stream.readline()`` gives it."""
    fd = _descriptor(stream)
    if fd is None:
        return stream.readline()
    encoding = getattr(stream, "encoding", None) or "utf-8"
    data = bytearray()
    while True:
        ready, _, _ = select.select([fd], [], [], POLL_S)
        if not ready:
            continue
        byte = os.read(fd, 1)
        if not byte:
            break
        data += byte
        if byte == b"\n":
            break
    return data.decode(encoding, errors="replace")


def _descriptor(stream: TextIO) -> int | None:
    """The stream's file descriptor when it can be waited on.

    Nothing else in the agent reads standard input, so its text buffer above the descriptor
    stays empty and reading below it loses nothing."""
    if sys.platform == "win32":  # select() waits on sockets only there
        return None
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return None  # an in-memory stream (tests, embedding)
    return fd
