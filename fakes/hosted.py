"""A simulated controller built and run in a process of its own, behind the simulated-controller contract.

A fake served by threads of the agent's process shares its interpreter lock and its share of a busy
host with the agent's reader, watchdog and analysis threads: under load it answers late for reasons no
real controller has (a pty-served Modbus RTU device left requests unanswered for over a second with both
cores busy), and the agent rightly stops the arm. In a process of its own the fake is scheduled by the
operating system like the separate device it stands for. The Elite EC and the Modbus fakes run
this way (a simulated EC66 serving its 125 Hz monitor stream from the agent's process stalled it past the
1 s watchdog once on a busy CI host); ``fakes/ur/process.py`` does the same for UR, whose client library
holds the lock while it connects.

``HostedController(factory, config)`` starts ``python -m payload_agent.fakes.hosted FD`` (FD: its end of a
socket pair, as ``fakes/ur/child.py``; not multiprocessing's spawn, which would re-run the parent's main
script), which calls ``factory``'s
``from_config(config, in_process=True)`` and serves requests over a pipe: method calls and attribute
reads on the controller and on its ``robot`` (``snapshot()``, ``payload``, ...). Results and errors
travel pickled; the command log's times are ``time.monotonic()``, one clock for both processes on Linux.
The child ends when it is closed or when the parent goes away (its end of the pipe closes).
"""

from __future__ import annotations

import importlib
import pickle
import socket
import subprocess
import sys
import threading
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

from payload_agent.fakes.base import ControllerEvent, SimulatedController

if TYPE_CHECKING:
    from payload_agent.configuration.config import Config
    from payload_agent.drivers.base import DriverOptions

START_TIMEOUT_S = 60.0  # the child imports numpy and the physics before it answers (slow on a loaded host)
REPLY_TIMEOUT_S = 30.0
_CALLABLE = "<callable>"


def _portable(exc: BaseException) -> BaseException:
    """The exception itself if it survives pickling, else a RuntimeError with its type and text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError(f"in the simulated controller's process: {type(exc).__name__}: {exc}")


def _serve(conn: Connection) -> None:
    """The child: build the controller, then answer (op, path, args, kwargs) requests until closed."""
    try:
        factory, config = conn.recv()
        module, _, name = factory.partition(":")
        ctrl = getattr(importlib.import_module(module), name).from_config(config, in_process=True)
    except BaseException as exc:
        conn.send(("error", _portable(exc)))
        return
    conn.send(("ok", None))
    try:
        while True:
            try:
                op, path, args, kwargs = conn.recv()
            except (EOFError, OSError):
                break  # the parent went away
            if (op, path) == ("call", "close"):
                break  # closed below, then answered
            try:
                owner = ctrl
                *owners, last = path.split(".")
                for part in owners:
                    owner = getattr(owner, part)
                value = getattr(owner, last)
                if op == "call":
                    value = value(*args, **kwargs)
                    value = None if path == "start" else value  # start() returns the controller: it stays here
                elif callable(value):
                    value = _CALLABLE
                conn.send(("ok", value))
            except BaseException as exc:
                conn.send(("error", _portable(exc)))
    finally:
        try:
            ctrl.close()
        except Exception:
            pass
        try:
            conn.send(("ok", None))
        except (OSError, ValueError):
            pass


class _Remote:
    """Attribute reads and method calls on an object that lives in the child (``robot``)."""

    def __init__(self, host: "HostedController", path: str):
        self._host, self._path = host, path

    def __getattr__(self, name: str) -> Any:
        return self._host.remote_attr(f"{self._path}.{name}")


class HostedController(SimulatedController):
    """The parent's side: every call goes to the controller in the child."""

    def __init__(self, factory: str, config: "Config", faults: frozenset[str] = frozenset()):
        super().__init__()
        self.faults = faults
        self._lock = threading.Lock()
        self._closed = False
        self._final: dict[tuple[str, str], Any] = {}  # (op, path) -> value, read before the close
        self._methods: set[str] = set()  # paths the child said are methods: called without asking again
        parent_sock, child_sock = socket.socketpair()
        self._proc = subprocess.Popen([sys.executable, "-m", "payload_agent.fakes.hosted", str(child_sock.fileno())],
                                      pass_fds=(child_sock.fileno(),), close_fds=True)
        child_sock.close()
        self._conn = Connection(parent_sock.detach())
        try:
            self._conn.send((factory, config))
            self._reply(START_TIMEOUT_S, "start")
        except BaseException:
            self._end_process()
            raise

    @classmethod
    def from_config(cls, config: "Config") -> "HostedController":
        raise TypeError("a HostedController is made by its controller class's from_config")

    # -- the pipe ---------------------------------------------------------------------------------
    def _reply(self, timeout_s: float, what: str) -> Any:
        try:
            if not self._conn.poll(timeout_s):
                raise RuntimeError(f"the simulated controller's process did not answer {what} within {timeout_s:g} s")
            status, value = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise RuntimeError(f"the simulated controller's process ended ({what}): exit code "
                               f"{self._proc.poll()}") from exc
        if status == "error":
            raise value
        return value

    def _request(self, op: str, path: str, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            if self._closed:
                if (op, path) in self._final:  # what an in-process controller still tells after its close
                    return self._final[(op, path)]
                raise RuntimeError(f"the simulated controller is closed ({path})")
            self._conn.send((op, path, args, kwargs))
            return self._reply(REPLY_TIMEOUT_S, path)

    def remote_attr(self, path: str) -> Any:
        """The value of ``path`` in the child, or a function calling it there if it is a method.

        A method stays a method: once the child said so, later uses call it in one round trip instead of two
        (tests poll ``robot.snapshot()`` every few milliseconds). A value is asked for every time."""
        if path not in self._methods:
            value = self._request("get", path)
            if not (isinstance(value, str) and value == _CALLABLE):
                return value
            self._methods.add(path)
        return lambda *args, **kwargs: self._request("call", path, *args, **kwargs)

    def __getattr__(self, name: str) -> Any:  # the controller's own extras (payload_setting, stop_program, ...)
        if name.startswith("_"):
            raise AttributeError(name)
        return self.remote_attr(name)

    # -- the contract ---------------------------------------------------------------------------
    def start(self) -> "HostedController":
        self._request("call", "start")
        return self

    def close(self) -> None:
        if not self._closed:
            try:  # the command log and the arm's last state stay readable, as an in-process controller's do
                for key in (("get", "events"), ("call", "robot.snapshot")):
                    self._final[key] = self._request(*key)
                self._final[("get", "robot.snapshot")] = _CALLABLE
            except Exception:
                pass
            try:
                self._request("call", "close")
            except Exception:
                pass
            self._closed = True
        self._end_process()

    def _end_process(self) -> None:
        try:
            self._proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(timeout=5.0)
        self._conn.close()

    def bound_options(self, options: "DriverOptions") -> "DriverOptions":
        return self._request("call", "bound_options", options)

    @property
    def robot(self) -> Any:
        return _Remote(self, "robot")

    def set_payload(self, truth) -> None:
        self._request("call", "set_payload", truth)

    @property
    def payload(self):
        return self._request("get", "payload")

    def set_friction_scale(self, scale: float) -> None:
        self._request("call", "set_friction_scale", scale)

    def inject_fault(self, name: str, **params: Any) -> None:
        self._request("call", "inject_fault", name, **params)

    def clear_faults(self) -> None:
        self._request("call", "clear_faults")

    def _apply_fault(self, name: str, params: dict[str, Any]) -> None:  # (inject_fault goes to the child whole)
        self._request("call", "inject_fault", name, **params)

    def record_event(self, kind: str, detail: str = "") -> None:
        self._request("call", "record_event", kind, detail)

    @property
    def events(self) -> list[ControllerEvent]:
        return self._request("get", "events")


if __name__ == "__main__":
    if len(sys.argv) != 2 or not sys.argv[1].isdigit():
        sys.exit("usage: python -m payload_agent.fakes.hosted FD (started by HostedController)")
    _serve(Connection(int(sys.argv[1])))
