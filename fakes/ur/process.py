"""``FakeURController``: the simulated UR e-Series controller behind the simulated-controller contract,
hosted in a child process.

ur_rtde's Python constructors (RTDEReceiveInterface, RTDEControlInterface) keep the GIL while
they connect and wait for the controller's replies (rtde_python_bindings.cpp: ``py::init<...>()``
without ``py::call_guard<py::gil_scoped_release>``), so a fake served by Python threads of the
*same* process can never answer them. The controller (``URControllerCore``) therefore runs in a
process of its own (``python -m payload_agent.fakes.ur.child``); the parent talks to it over a
socket pair: ``robot`` is a proxy with the ``SimRobot`` methods, the command log (``events``)
is recorded in the child and read from here, faults are injected there.

Test-side API::

    with FakeURController(time_scale=1.0, payload=PayloadTruth(...)) as ur:   # host: a free 127.0.0.x
        ur.host; ur.robot.snapshot(); ur.robot.set_payload(...)
        ur.inject_fault("stall_stream"); ur.clear_faults(); ur.events
        ur.trigger_protective_stop(); ur.set_remote_control(False); ur.set_tcp_offset([...])
        ur.set_digital_input(3, True); ur.set_joint_temperatures([35.0] * 6)
        ur.controller_payload, ur.script_errors, ur.rtde_errors, ur.log, ur.programs_run

Options (keywords): spec (ArmSpec, default UR5e), q0_rad, time_scale, tick_s (0.002 = 500 Hz),
friction, noise_nm, seed, payload, sim_options (further SimRobot keywords), gains_nm_per_a,
current_noise_a, gain_error, controller_version, serial_number, robot_model, remote_control,
max_payload_kg, tcp_offset, ports, keep_payload_inertia (set_target_payload keeps the old inertia:
a controller whose readback differs from what was written), script_start_delay_s (a control script runs
this long before its first register write; until then the registers hold the previous program's values).
"""

from __future__ import annotations

import collections
import dataclasses
import pickle
import socket
import threading
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from payload_agent.fakes.base import ControllerEvent, SimulatedController, sim_robot_kwargs
from payload_agent.fakes.ur.controller import URControllerCore
from payload_agent.fakes.ur.faults import UR_FAULTS

if TYPE_CHECKING:
    from payload_agent.configuration.config import Config
    from payload_agent.drivers.base import DriverOptions
    from payload_agent.fakes.sim_robot import SimRobot

UR_TICK_S = 0.002  # e-Series control cycle: 500 Hz
_ROBOT_METHODS = {"now", "snapshot", "set_payload", "set_friction_scale", "set_servo", "trigger_protective_stop",
                  "trigger_estop", "reset_safety", "stop", "move_joints"}
_ROBOT_ATTRS = {"payload", "spec", "time_scale", "tick_s"}


def _ctrl_calls(core: URControllerCore) -> dict[str, Callable[..., Any]]:
    return {"trigger_protective_stop": core.trigger_protective_stop, "trigger_estop": core.trigger_estop,
            "release_estop": core.release_estop, "reset_safety": core.reset_safety,
            "set_remote_control": core.set_remote_control, "set_digital_input": core.set_digital_input,
            "set_joint_temperatures": core.set_joint_temperatures, "set_tcp_offset": core.set_tcp_offset,
            "run_script": core.programs.run_script, "wait_ticks": core.wait_ticks,
            "apply_fault": core.faults.apply, "clear_fault": core.faults.clear, "record_event": core.record_event}


def _ctrl_attrs(core: URControllerCore) -> dict[str, Callable[[], Any]]:
    return {"last_script": lambda: core.programs.last_script, "programs_run": lambda: core.programs.programs_run,
            "runtime_state": lambda: core.runtime_state, "robot_mode": lambda: core.robot_mode,
            "script_errors": lambda: core.script_errors, "rtde_errors": lambda: core.rtde_errors,
            "log": lambda: core.log, "events": lambda: core.events, "gain_error": lambda: core.gain_error,
            "controller_payload": lambda: core.controller_payload, "gains": lambda: core.gains,
            "current_noise_a": lambda: core.current_noise_a, "controller_version": lambda: core.controller_version,
            "serial_number": lambda: core.serial_number, "out_int": lambda: core.out_int,
            "out_dbl": lambda: core.out_dbl, "in_int": lambda: core.in_int, "in_dbl": lambda: core.in_dbl,
            "digital_in": lambda: core.digital_in, "joint_temperatures": lambda: core.joint_temperatures,
            "tcp_offset": lambda: core.tcp_offset, "stream_packages_sent": lambda: _stream_packages_sent(core)}


# what the parent may read (``FakeURController.<name>``); _ctrl_attrs answers each in the child
CTRL_ATTR_NAMES = frozenset({"last_script", "programs_run", "runtime_state", "robot_mode", "script_errors",
                             "rtde_errors", "log", "events", "gain_error", "controller_payload", "gains",
                             "current_noise_a", "controller_version", "serial_number", "out_int", "out_dbl",
                             "in_int", "in_dbl", "digital_in", "joint_temperatures", "tcp_offset",
                             "stream_packages_sent"})


def _stream_packages_sent(core: URControllerCore) -> int:
    """Data packages sent so far to the open sample stream sessions (not the control interface's)."""
    with core.lock:
        return sum(s.sent_packages for s in core.rtde_sessions if s.is_sample_stream)


def _copy_out(value: Any) -> Any:
    if isinstance(value, (collections.deque, list)):
        return list(value)
    if isinstance(value, np.ndarray):
        return value.copy()
    return value


def child_main(conn) -> None:
    """The child process: build and start the controller, then answer the parent's requests."""
    import sys

    # The controller's threads (clock, RTDE senders, program) hand the GIL to each other
    # every cycle; the default 5 ms switch interval would add up to 5 ms jitter to 2 ms cycles.
    sys.setswitchinterval(0.0002)
    try:
        host, options = conn.recv()
        core = URControllerCore(host, **options).start()
    except BaseException as exc:  # report, then exit
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ok", core.host))
    calls, attrs = _ctrl_calls(core), _ctrl_attrs(core)
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            op = msg[0]
            if op == "close":
                break
            try:
                if op == "call" and msg[1] == "robot":
                    if msg[2] not in _ROBOT_METHODS:
                        raise AttributeError(msg[2])
                    result = getattr(core.robot, msg[2])(*msg[3], **msg[4])
                elif op == "call":
                    result = calls[msg[2]](*msg[3], **msg[4])
                elif op == "get" and msg[1] == "robot":
                    if msg[2] not in _ROBOT_ATTRS:
                        raise AttributeError(msg[2])
                    result = getattr(core.robot, msg[2])
                elif op == "get":
                    result = _copy_out(attrs[msg[2]]())
                else:
                    raise ValueError(f"unknown request {op!r}")
                conn.send(("ok", result))
            except Exception as exc:
                conn.send(("exc", exc if _picklable(exc) else RuntimeError(repr(exc))))
    finally:
        core.close()
        try:
            conn.send(("closed", None))
        except (OSError, ValueError):
            pass


def _picklable(obj) -> bool:
    try:
        pickle.dumps(obj)
        return True
    except Exception:
        return False


class _RemoteRobot:
    """Parent-side stand-in for the child's ``SimRobot`` (same method names)."""

    def __init__(self, owner: "FakeURController"):
        self._owner = owner

    def start(self) -> "_RemoteRobot":
        """Starts the controller that owns the simulation (the clock runs in its process)."""
        self._owner.start()
        return self

    def close(self) -> None:
        """No-op: the simulation ends with ``FakeURController.close()``."""

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        if name in _ROBOT_METHODS:
            return lambda *a, **kw: self._owner._request(("call", "robot", name, a, kw))
        if name in _ROBOT_ATTRS:
            return self._owner._request(("get", "robot", name))
        raise AttributeError(name)


class FakeURController(SimulatedController):
    """A simulated UR e-Series controller serving ``host`` (127.0.0.x; a free one is picked if None).

    By default the controller runs in a child process (see the module note): ``robot`` is then
    a proxy with the ``SimRobot`` methods. ``in_process=True`` runs it in this process (raw-socket
    tests; a ``SimRobot`` may be passed as ``sim``), which real ur_rtde clients of this process
    cannot talk to.
    """

    faults = UR_FAULTS

    def __init__(self, host: str | None = None, sim: "SimRobot | None" = None, *, in_process: bool = False,
                 start_timeout_s: float = 30.0, **options):
        super().__init__()
        if "robot" in options:
            raise TypeError("FakeURController takes no 'robot': the simulation runs in the controller's own process "
                            "(ur_rtde's constructors hold the GIL); pass spec=, q0_rad=, time_scale=, friction=, "
                            "noise_nm=, seed=, payload= and use the controller's .robot proxy for tool changes")
        if sim is not None and not in_process:
            raise TypeError("a SimRobot instance cannot be moved to the controller's process; pass the simulation "
                            "options (spec, q0_rad, time_scale, payload, friction, ...) or use in_process=True")
        self.host = host
        self.in_process = in_process
        self._sim = sim
        self._options = options
        self._start_timeout_s = start_timeout_s
        self._core: URControllerCore | None = None
        self._proc = None
        self._conn = None
        self._req_lock = threading.Lock()
        self._robot: Any = sim if in_process and sim is not None else _RemoteRobot(self)
        self._final_events: list[ControllerEvent] = []

    # -- the simulated-controller contract ---------------------------------------------------------
    @classmethod
    def from_config(cls, config: "Config") -> "FakeURController":
        """The fake a sim-*.yaml asks for: its arm, truth-free start, friction, noise, drive gains.

        The drives report current = torque / gain × drive_gain_error with the YAML's own
        ``effort.gains_nm_per_unit``, so the config describes the simulated robot exactly; the
        sensor noise is ``simulation.noise_nm`` on the torque (no extra current noise).
        ``driver.host: auto`` (or none) picks a free 127.0.0.x.
        """
        from payload_agent.errors import ConfigError
        from payload_agent.fakes.arms import SPECS, simulated_spec

        sim = config.simulation
        if sim is None:
            raise ConfigError("simulation", "this config has no simulation section")
        if config.effort.unit != "A":
            raise ConfigError("effort.unit", f"the simulated UR controller reports motor current in A, "
                                             f"not {config.effort.unit!r}")
        if sim.arm not in SPECS:
            raise ConfigError("simulation.arm", f"unknown simulated arm {sim.arm!r}; known: {', '.join(SPECS)}")
        kwargs = sim_robot_kwargs(config)
        known = {"q0_rad", "time_scale", "friction", "noise_nm", "seed", "payload"}
        extra = {k: v for k, v in kwargs.items() if k not in known}
        kwargs = {k: v for k, v in kwargs.items() if k in known}
        kwargs["q0_rad"] = tuple(float(v) for v in kwargs["q0_rad"])
        opts = config.driver_options
        host = getattr(opts, "host", None) if opts is not None else config.driver.get("host")
        return cls(host=None if host in (None, "", "auto") else str(host), spec=simulated_spec(sim), tick_s=UR_TICK_S,
                   gain_error=tuple(sim.drive_gain_error), gains_nm_per_a=tuple(config.effort.gains_nm_per_unit),
                   current_noise_a=0.0, sim_options=extra or None, **kwargs)

    def bound_options(self, options: "DriverOptions") -> "DriverOptions":
        if self.host is None:
            raise RuntimeError("the fake UR controller has not started: no address yet")
        return dataclasses.replace(options, host=self.host)

    @property
    def robot(self) -> Any:
        return self._robot

    def _apply_fault(self, name: str, params: dict[str, Any]) -> None:
        self._request(("call", "ctrl", "apply_fault", (name, params), {}))

    def _clear_fault(self, name: str) -> None:
        self._request(("call", "ctrl", "clear_fault", (name,), {}))

    def record_event(self, kind: str, detail: str = "") -> None:
        self._request(("call", "ctrl", "record_event", (kind, detail), {}))

    @property
    def events(self) -> list[ControllerEvent]:
        """Every move / stop / payload command the controller accepted (recorded where it runs; kept after close)."""
        if self._core is None and self._proc is None:
            return list(self._final_events)
        return list(self._request(("get", "ctrl", "events")))

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> "FakeURController":
        if self._core is not None or self._proc is not None:
            return self
        if self.in_process:
            self._core = URControllerCore(self.host, self._sim, **self._options).start()
            self.host = self._core.host
            self._robot = self._core.robot
            return self
        import subprocess
        import sys
        from multiprocessing.connection import Connection

        parent_sock, child_sock = socket.socketpair()
        proc = subprocess.Popen([sys.executable, "-m", "payload_agent.fakes.ur.child", str(child_sock.fileno())],
                                pass_fds=(child_sock.fileno(),), close_fds=True)
        child_sock.close()
        parent = Connection(parent_sock.detach())
        try:
            parent.send((self.host, self._options))
            if not parent.poll(self._start_timeout_s):
                raise RuntimeError("the fake UR controller process did not start in time")
            status, value = parent.recv()
        except (OSError, EOFError, RuntimeError) as exc:
            proc.kill()
            proc.wait(timeout=5)
            parent.close()
            raise RuntimeError(f"the fake UR controller process failed to start: {exc}") from exc
        if status != "ok":
            proc.wait(timeout=5)
            parent.close()
            raise RuntimeError(f"the fake UR controller could not start: {value}")
        self.host = value
        self._proc, self._conn = proc, parent
        return self

    def close(self) -> None:
        try:
            if self._core is not None or self._proc is not None:
                self._final_events = self.events
        except Exception:  # the child is gone: its log with it
            pass
        if self._core is not None:
            self._core.close()
            self._core = None
            return
        if self._proc is None:
            return
        try:
            with self._req_lock:
                self._conn.send(("close",))
                if self._conn.poll(5.0):
                    self._conn.recv()
        except (OSError, EOFError, BrokenPipeError):
            pass
        try:
            self._proc.wait(timeout=5.0)
        except Exception:  # a busy host: ended now; once killed it is gone whenever the kernel gets to it
            self._proc.kill()
            try:
                self._proc.wait(timeout=10.0)
            except Exception:
                pass
        self._conn.close()
        self._proc = self._conn = None

    def __enter__(self) -> "FakeURController":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _request(self, msg):
        if self._core is not None:  # in process
            if msg[0] == "call":
                _, target, name, args, kwargs = msg
                fn = getattr(self._core.robot, name) if target == "robot" else _ctrl_calls(self._core)[name]
                return fn(*args, **kwargs)
            if msg[1] == "robot":
                return getattr(self._core.robot, msg[2])
            return _copy_out(_ctrl_attrs(self._core)[msg[2]]())
        if self._conn is None:
            raise RuntimeError("the fake UR controller is not running")
        with self._req_lock:
            self._conn.send(msg)
            status, value = self._conn.recv()
        if status == "exc":
            raise value
        return value

    # -- test-side API ------------------------------------------------------------------------------
    def _call(self, name: str, *args) -> Any:
        return self._request(("call", "ctrl", name, args, {}))

    def trigger_protective_stop(self) -> None:
        self._call("trigger_protective_stop")

    def trigger_estop(self) -> None:
        self._call("trigger_estop")

    def release_estop(self) -> None:
        self._call("release_estop")

    def reset_safety(self) -> None:
        self._call("reset_safety")

    def set_remote_control(self, on: bool) -> None:
        self._call("set_remote_control", bool(on))

    def set_digital_input(self, index: int, value: bool) -> None:
        self._call("set_digital_input", index, value)

    def set_joint_temperatures(self, values: Sequence[float], steady: Sequence[float] | None = None) -> None:
        self._call("set_joint_temperatures", [float(v) for v in values],
                   None if steady is None else [float(v) for v in steady])

    def set_tcp_offset(self, pose: Sequence[float]) -> None:
        """The installation's TCP (what set_tcp() would set): [x, y, z, rx, ry, rz], m and rotation vector."""
        self._call("set_tcp_offset", [float(v) for v in pose])

    def run_script(self, text: str, source: str = "test") -> None:
        self._call("run_script", text, source)

    def wait_ticks(self, n: int = 1, timeout: float = 5.0) -> None:
        self._call("wait_ticks", n, timeout)

    def __getattr__(self, name: str):
        if name in CTRL_ATTR_NAMES:
            return self._request(("get", "ctrl", name))
        raise AttributeError(name)
