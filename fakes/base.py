"""The simulated-controller contract every fake implements, whatever protocol it speaks.

A simulated controller serves one ``SimRobot`` (the physics core) on a loopback address
through the real protocol. The agent finds it through the driver registry
(``Driver.simulator``), never through an if/else, and tests and the fault matrix drive
every fake through the same few calls:

- ``from_config(config)`` builds the robot and the controller from a robot YAML's
  ``simulation`` section and driver options; ``start()`` / ``close()``;
- ``bound_options(options)``: the driver options rewritten to where the fake really listens
  (ephemeral ports, an automatically chosen 127.0.0.x);
- ``set_payload`` / ``payload`` (the truth), ``set_friction_scale`` (drift at a tool change);
- ``inject_fault(name)`` with the common names in ``FAULTS``; ``clear_faults()``;
- ``events``: every motion and stop command the controller accepted, with its receive time,
  so a test can tell when a stop arrived and that no motion followed a fault; a controller the
  agent asks only now and then also logs the first request a reply fault held back (``withheld``).
"""

from __future__ import annotations

import abc
import ipaddress
import random
import socket
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Sequence

import numpy as np

if TYPE_CHECKING:  # the fakes read a Config; they never import the agent's later stages
    from payload_agent.configuration.config import Config
    from payload_agent.drivers.base import DriverOptions
    from payload_agent.fakes.physics import PayloadTruth

FAULTS = (
    "drop_connections",  # close every client connection (command and stream)
    "stall_stream",  # stop sending samples; the command channel keeps working
    "garbage",  # the sample stream sends bytes that do not parse
    "nan_values",  # samples carry NaN / inf
    "protective_stop",
    "emergency_stop",
    "leave_remote",  # the pendant takes control back (teach / local mode)
    "slow_reply",  # command replies come, far too late
    "no_reply",  # command requests are swallowed
    "never_finish",  # a motion never reports finished
)


@dataclass(frozen=True)
class ControllerEvent:
    t: float  # time.monotonic() when the controller received it
    kind: str  # "move" | "stop" | "payload" | ...
    detail: str = ""


class SimulatedController(abc.ABC):
    """Base of every fake controller; subclasses fill the protocol."""

    faults: ClassVar[frozenset[str]] = frozenset()  # the FAULTS this controller can inject

    def __init__(self) -> None:
        self._events: list[ControllerEvent] = []
        self._events_lock = threading.Lock()
        self.active_faults: dict[str, dict[str, Any]] = {}

    @classmethod
    @abc.abstractmethod
    def from_config(cls, config: "Config") -> "SimulatedController":
        """Build the simulated robot and this controller from a robot YAML (``simulation`` section)."""

    @abc.abstractmethod
    def start(self) -> "SimulatedController": ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def bound_options(self, options: "DriverOptions") -> "DriverOptions":
        """The driver options pointed at where this fake listens."""

    @property
    @abc.abstractmethod
    def robot(self) -> Any:
        """The SimRobot (or a proxy to it in another process)."""

    # -- truth ----------------------------------------------------------------------------------
    def set_payload(self, truth: "PayloadTruth | None") -> None:
        self.robot.set_payload(truth)

    @property
    def payload(self) -> "PayloadTruth | None":
        return self.robot.payload

    def set_friction_scale(self, scale: float) -> None:
        self.robot.set_friction_scale(scale)

    # -- faults ---------------------------------------------------------------------------------
    def inject_fault(self, name: str, **params: Any) -> None:
        if name not in FAULTS:
            raise ValueError(f"unknown fault {name!r}; known: {', '.join(FAULTS)}")
        if name not in self.faults:
            raise ValueError(f"{type(self).__name__} cannot inject {name!r}; it can: {', '.join(sorted(self.faults))}")
        self.active_faults[name] = dict(params)
        self._apply_fault(name, params)

    def clear_faults(self) -> None:
        for name in list(self.active_faults):
            self._clear_fault(name)
        self.active_faults.clear()

    @abc.abstractmethod
    def _apply_fault(self, name: str, params: dict[str, Any]) -> None: ...

    def _clear_fault(self, name: str) -> None:
        """Undo a fault where that makes sense (a stalled stream resumes); default: nothing."""

    # -- command log ----------------------------------------------------------------------------
    def record_event(self, kind: str, detail: str = "") -> None:
        with self._events_lock:
            self._events.append(ControllerEvent(time.monotonic(), kind, detail))

    @property
    def events(self) -> list[ControllerEvent]:
        with self._events_lock:
            return list(self._events)

    def first_event_after(self, kind: str, t: float) -> ControllerEvent | None:
        return next((e for e in self.events if e.kind == kind and e.t >= t), None)


def require_loopback(host: str) -> str:
    """Simulated controllers serve loopback only: refuse any other address before binding."""
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError as exc:
        raise OSError(f"simulated controller: cannot resolve {host!r}: {exc}") from None
    for info in infos:
        if not ipaddress.ip_address(info[4][0]).is_loopback:
            raise OSError(f"simulated controllers listen on loopback addresses only (127.0.0.0/8, ::1), "
                          f"not {host!r}")
    return host


def free_loopback_host(ports: Sequence[int], attempts: int = 50) -> str:
    """A 127.0.0.x address (x in 2..250) on which every one of ``ports`` can be bound now: a simulated
    controller with its protocol's fixed ports (a YAML's ``host: auto``) beside other simulations."""
    rng = random.Random()
    for _ in range(attempts):
        host = f"127.0.0.{rng.randint(2, 250)}"
        socks = []
        try:
            for port in ports:
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                socks.append(s)
                s.bind((host, port))
            return host
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise OSError(f"no 127.0.0.x address has ports {', '.join(map(str, ports))} free")


def sim_robot_kwargs(config: "Config") -> dict[str, Any]:
    """The SimRobot keyword arguments a robot YAML's ``simulation`` section asks for."""
    from payload_agent.fakes.effects import from_simulation as effects_from_simulation
    from payload_agent.fakes.physics import FrictionParams

    sim = config.simulation
    return dict(
        q0_rad=np.radians(sim.start_deg), time_scale=sim.time_scale,
        friction=FrictionParams(np.array(sim.coulomb_nm), np.array(sim.viscous_nm_s_rad), np.array(sim.load_ratio)),
        noise_nm=np.array(sim.noise_nm),
        noise_rest_nm=None if sim.noise_rest_nm is None else np.array(sim.noise_rest_nm), seed=sim.seed, payload=None, effects=effects_from_simulation(sim),
        **({"session": sim.session} if sim.session else {}), noise_per_move=sim.noise_per_move)
