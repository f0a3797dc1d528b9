"""The UR command channel: ur-rtde's control interface, in a worker process, every call bounded.

``RTDEControlInterface`` uploads ur-rtde's control script (port 30003) and talks to it through
RTDE registers. It runs in a worker process of its own (``control_worker.py``) because:

* when the controller drops the connection, ur-rtde 1.6 reconnects from inside its own receive
  thread (``RTDEControlInterface::receiveCallback`` calls ``reconnect()``), starts a second
  receive thread on the same socket and then crashes the process (segmentation fault: seen
  every time against the simulated controller). A crash there must not take the agent, its
  recorder and its stop over the dashboard with it;
* its Python constructor holds the GIL while it waits for the controller (no
  ``gil_scoped_release`` in ur-rtde's bindings), which would stall the agent's sample reader and
  motion watchdog for as long as the script upload takes;
* its calls wait for the script with ur-rtde's own timeouts (up to 300 s): a worker that does not
  answer in time is killed, and the next command starts a new one.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Callable

import rtde_control

from payload_agent.errors import CommunicationError, RobotNotReadyError

RTDE_PORT = 30004
WORKER = Path(__file__).with_name("control_worker.py")
COMMAND_TIMEOUT_S = 2.0  # a ur-rtde command (moveJ async, setPayload, getTCPOffset) answers in a few cycles
OPEN_TIMEOUT_S = 15.0  # worker start + ur-rtde's constructor (dashboard, recipes, script upload: 5 s limit)


class ControlChannel:
    """One control interface to ``host`` in a worker process (or none yet)."""

    def __init__(self, host: str, frequency_hz: float, upper_range_registers: bool):
        self.host = host
        self.frequency_hz = frequency_hz
        self.upper_range_registers = upper_range_registers
        self.lock = threading.Lock()  # one command sequence at a time (moves, payload, TCP)
        self._io = threading.Lock()  # one request on the worker's socket at a time
        self._proc: subprocess.Popen | None = None
        self._conn: Connection | None = None
        self.broken = False  # a request failed or hung: the next use starts a new worker
        self.connected = False  # isConnected() as of the last reply
        self.program_running = False  # isProgramRunning() as of the last reply

    def alive(self) -> bool:
        proc = self._proc
        return proc is not None and not self.broken and self.connected and proc.poll() is None

    def ready(self) -> bool:
        """Alive with the control script running (no upload needed)."""
        return self.alive() and self.program_running

    def request(self, op: str, *args: Any, timeout_s: float, what: str | None = None,
                lock_timeout_s: float | None = None) -> Any:
        """One request to the worker; CommunicationError on a timeout (worker then killed) or a failure."""
        what = what or op
        if self._conn is None or self.broken:
            raise CommunicationError(f"UR controller {self.host}: no control interface for {what}")
        if not self._io.acquire(timeout=-1 if lock_timeout_s is None else lock_timeout_s):
            raise CommunicationError(f"UR controller {self.host}: the control interface is busy; {what} not sent")
        try:
            try:
                self._conn.send((op, *args))
                ready = self._conn.poll(timeout_s)
                reply = self._conn.recv() if ready else None
            except (OSError, EOFError) as exc:
                self._fail()
                raise CommunicationError(f"UR controller {self.host}: the control interface ended during {what} "
                                         f"({type(exc).__name__})") from None
            if reply is None:
                self._fail()
                raise CommunicationError(f"UR controller {self.host}: no reply to {what} within {timeout_s:.2f} s "
                                         "(ur-rtde's control script does not answer)")
        finally:
            self._io.release()
        self.connected, self.program_running = reply[-1]
        if reply[0] == "error":
            _, kind, text, _ = reply
            if "remote control" in text:
                raise RobotNotReadyError(f"UR controller {self.host}: the teach pendant is not in Remote Control; "
                                         f"switch it to Remote Control ({text})")
            raise CommunicationError(f"UR controller {self.host}: {what} failed: {kind}: {text}")
        return reply[1]

    def get(self, not_ready: Callable[[], str]) -> bool:
        """Make sure the control script runs; True if the interface was just built or re-uploaded.

        ``not_ready()`` says why the robot would refuse the script ("" if it would not).
        """
        if self._proc is not None and not self.alive():
            self.discard()
        if self._proc is not None:
            self.request("status", timeout_s=1.0)
            if self.program_running:
                return False
            reason = not_ready()
            if reason:
                raise RobotNotReadyError(f"UR controller {self.host}: {reason}")
            if not self.request("reuploadScript", timeout_s=6.0):
                raise CommunicationError(f"UR controller {self.host}: could not re-upload ur-rtde's control script")
            deadline = time.monotonic() + 5.0
            while not self.program_running:
                if time.monotonic() > deadline:
                    raise CommunicationError(f"UR controller {self.host}: the control script did not start")
                time.sleep(0.005)
                self.request("status", timeout_s=1.0)
            return True
        self._start_worker()
        flags = rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT
        if self.upper_range_registers:
            flags |= rtde_control.RTDEControlInterface.FLAG_UPPER_RANGE_REGISTERS
        try:
            self.request("open", self.host, float(self.frequency_hz), int(flags), timeout_s=OPEN_TIMEOUT_S,
                         what="connecting the RTDE control interface")
        except CommunicationError as exc:
            self.discard()
            reason = not_ready()
            if reason:
                raise RobotNotReadyError(f"UR controller {self.host}: {reason} ({exc})") from None
            raise
        except RobotNotReadyError:
            self.discard()
            raise
        if not self.connected:
            self.discard()
            raise CommunicationError(f"RTDE control interface to {self.host}:{RTDE_PORT} did not connect")
        return True

    def stop(self, decel_rad_s2: float, timeout_s: float) -> bool:
        """stopJ, asynchronous: True once the script took it.

        ur-rtde's stopJ returns nothing: it returns when the script has signalled "done", or at once
        without sending when the script is not running (a safety stop ended it). So the stop counts
        as acknowledged only if the script still runs after the call.
        """
        if not self.ready():
            return False
        try:
            self.request("stopJ", decel_rad_s2, True, timeout_s=timeout_s, lock_timeout_s=timeout_s)
        except CommunicationError:
            return False
        return self.connected and self.program_running

    def _start_worker(self) -> None:
        parent, child = socket.socketpair()
        try:
            self._proc = subprocess.Popen([sys.executable, str(WORKER), str(child.fileno())],
                                          pass_fds=(child.fileno(),), close_fds=True)
        finally:
            child.close()
        self._conn = Connection(parent.detach())
        self.broken = False
        self.connected = self.program_running = False

    def _fail(self) -> None:
        """The worker hung or died: mark the channel broken and end the worker."""
        self.broken = True
        self.connected = self.program_running = False
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()

    def discard(self) -> None:
        """End the worker (its sockets close with it). Never raises."""
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        self.broken = False
        self.connected = self.program_running = False
        if conn is not None:
            try:
                conn.close()
            except OSError:
                pass
        if proc is not None:
            try:
                proc.kill()
                proc.wait(timeout=2.0)
            except Exception:
                pass

    def close(self, timeout_s: float) -> None:
        """Stop ur-rtde's script (it would otherwise keep the robot program) and end the worker.

        The worker is ended, not asked to disconnect: ur-rtde's ``disconnect()`` sleeps 0.5 s, and the
        operating system closes the worker's connections as cleanly when it exits.
        """
        try:
            if self.ready():
                self.request("stopScript", timeout_s=timeout_s, lock_timeout_s=timeout_s)
        except Exception:
            pass
        self.discard()
