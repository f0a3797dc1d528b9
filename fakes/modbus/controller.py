"""A simulated robot behind a Modbus server (TCP or RTU), serving a register map from the physics core.

It implements the simulated-controller contract (``payload_agent.fakes.base``): the robot YAML's
``simulation`` section builds the ``SimRobot``; the driver options choose the map (preset plus
overrides), the transport and the unit id. Every control cycle (a tick of the robot's clock)
the handshake program runs (``program.HandshakeProgram``) and the sensor registers are
refreshed at the map's update rate (``image.SensorImage``). Move and stop commands are logged
when the server receives them (a write to ``cmd_seq`` or ``stop_request``).

Faults: drop_connections, stall_stream (registers stop updating), garbage (``mode="exception"``:
reads of the joint registers answered with exception 4; ``mode="values"``: impossible values),
nan_values (float32 maps), protective_stop, emergency_stop, leave_remote (the pendant takes
control: the program stops and the robot mode leaves its running value), slow_reply
(``delay_s``), no_reply, never_finish.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import TYPE_CHECKING, Any, Sequence

from payload_agent.drivers.modbus.handshake import KIND_PAYLOAD
from payload_agent.drivers.modbus.options import resolve_map
from payload_agent.drivers.modbus.regmap import RegisterMap
from payload_agent.fakes.base import FAULTS, SimulatedController, require_loopback, sim_robot_kwargs
from payload_agent.fakes.hosted import HostedController
from payload_agent.fakes.modbus.image import SAMPLE_SIGNALS, SensorImage
from payload_agent.fakes.modbus.program import HandshakeProgram
from payload_agent.fakes.modbus.server import ModbusServerThread
from payload_agent.fakes.modbus.store import RegisterStore, valid_ranges
from payload_agent.fakes.sim_robot import SimRobot, SimState

if TYPE_CHECKING:
    from payload_agent.configuration.config import Config
    from payload_agent.drivers.base import DriverOptions

DEFAULT_UPDATE_HZ = 125.0


def _float_signals(regmap: RegisterMap) -> bool:
    """Whether the map carries joint angles or efforts as float32 (where NaN can be injected)."""
    return any(regmap[n].type == "float32" for n in ("joint_angles", "joint_efforts"))


class SimulatedModbusRobot(SimulatedController):
    faults = frozenset(FAULTS)

    def __init__(self, robot: SimRobot, regmap: RegisterMap, *, gains: Sequence[float],
                 gain_error: Sequence[float] = (1.0,) * 6, transport: str = "tcp", host: str = "127.0.0.1",
                 unit_id: int = 1, baudrate: int = 115200, device_server: bool = False, owns_robot: bool = False):
        super().__init__()
        self._robot = robot
        self._owns_robot = owns_robot
        self.map = regmap
        self.transport = transport
        if not _float_signals(regmap):
            self.faults = frozenset(FAULTS) - {"nan_values"}
        self.store = RegisterStore(valid_ranges(list(regmap.entries.values()), regmap.bridge_gaps), unit_id,
                                   any_unit=(transport == "tcp"))
        self.store.on_write = self._on_write
        self.server = ModbusServerThread(self.store, transport, require_loopback(host), baudrate, device_server)
        self.image = SensorImage(self.store, regmap, robot.spec.dh, gains, gain_error)
        self.program = HandshakeProgram(self.store, regmap, robot, self.record_event)
        update = regmap.update_hz or DEFAULT_UPDATE_HZ
        self._every = max(1, int(round(1.0 / (update * robot.tick_s))))
        self._ticks = 0
        self._token: int | None = None
        self._started = False
        # Without a controller clock in the map the agent times samples on receipt, so simulated time
        # must keep up with wall time: the clock catches up on missed ticks instead of slowing down.
        self.wall_locked = "timestamp" not in regmap
        self._clock_thread: threading.Thread | None = None
        self._running = threading.Event()
        self._clock_lock = threading.Lock()
        self._t0 = 0.0
        self._done = 0

    @classmethod
    def from_config(cls, config: "Config", *, in_process: bool = False) -> "SimulatedModbusRobot | HostedController":
        """The simulated robot of the YAML's ``simulation`` section behind this map, in a process of its own
        (``fakes.hosted``: served beside the agent's threads, a pty device answered late under load, and a TCP
        server missed the 0.25 s reply timeout in 2 of 5 seeded runs), unless ``in_process`` (which is how that
        process builds it)."""
        from payload_agent.fakes.arms import simulated_spec

        sim = config.simulation
        if sim is None:
            raise ValueError("this config has no simulation section")
        opts = config.driver_options
        regmap = resolve_map(opts)
        cls._check_config(config, regmap)  # the YAML's mistakes named here, before any child process starts
        if not in_process:
            faults = frozenset(FAULTS) - ({"nan_values"} if not _float_signals(regmap) else set())
            return HostedController(f"{cls.__module__}:{cls.__name__}", config, faults)
        update = regmap.update_hz or DEFAULT_UPDATE_HZ
        robot = SimRobot(simulated_spec(sim), tick_s=1.0 / update, **sim_robot_kwargs(config))
        host = opts.host if opts.transport == "tcp" else "127.0.0.1"
        return cls(robot, regmap, gains=config.effort.gains_nm_per_unit, gain_error=sim.drive_gain_error,
                   transport=opts.transport, host=host or "127.0.0.1", unit_id=opts.unit_id,
                   baudrate=opts.baudrate, owns_robot=True,
                   # the YAML names a serial device server's TCP port (pyserial URL): the simulation stands one
                   # in front of its device, else a tty
                   device_server=opts.transport == "rtu" and opts.serial_port.startswith("socket://"))

    @staticmethod
    def _check_config(config: "Config", regmap: RegisterMap) -> None:
        from payload_agent.errors import ConfigError

        sim = config.simulation
        if config.effort.unit != regmap.effort_unit:
            raise ConfigError("effort.unit", f"the register map reports joint_efforts in {regmap.effort_unit!r}, "
                                             f"the YAML says {config.effort.unit!r}")
        if sim.time_scale != 1 and "timestamp" not in regmap:
            raise ConfigError("simulation.time_scale", f"this register map has no timestamp signal, so the agent "
                                                       f"times samples on receipt: the simulation must run in real "
                                                       f"time (time_scale: 1), not {sim.time_scale:g}")

    @property
    def robot(self) -> SimRobot:
        return self._robot

    def bound_options(self, options: "DriverOptions") -> "DriverOptions":
        if self.transport == "tcp":
            return dataclasses.replace(options, host=self.server.host, port=self.server.port)
        return dataclasses.replace(options, serial_port=self.server.client_path)

    def start(self) -> "SimulatedModbusRobot":
        if not self._started:
            self._started = True
            self.image.write(self._robot.snapshot())
            self.program.start()
            self.server.start()
            if self._owns_robot:  # our own clock: the controller cycle, one robot tick at a time
                self._running.set()
                self._t0 = time.monotonic()
                if self.wall_locked:
                    self.store.before_read = self._catch_up
                self._clock_thread = threading.Thread(target=self._clock, name="modbus-robot-clock", daemon=True)
                self._clock_thread.start()
            else:  # someone else runs the robot's clock
                self._token = self._robot.subscribe(self._on_tick)
        return self

    def close(self) -> None:
        self._running.clear()
        if self._clock_thread is not None:
            self._clock_thread.join(timeout=2.0)
            self._clock_thread = None
        if self._token is not None:
            self._robot.unsubscribe(self._token)
            self._token = None
        self.server.close()

    def _clock(self) -> None:
        period = self._robot.tick_s / self._robot.time_scale
        while self._running.is_set():
            self._catch_up()
            delay = self._t0 + (self._done + 1) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def _catch_up(self) -> None:
        """Run the control cycles that are due by now (from the clock thread, or before a read is served).

        A real controller never falls behind. When this process's threads are held up on a busy host,
        the due cycles run at once; with a wall-locked map a read also brings the device up to date first,
        so what it returns is the state at the time it was asked for, as with a real server.
        """
        with self._clock_lock:
            period = self._robot.tick_s / self._robot.time_scale
            due = int((time.monotonic() - self._t0) / period)
            if not self.wall_locked and due - self._done > 6:  # a timestamped map: slow simulated time instead
                self._t0 = time.monotonic() - self._done * period
                due = self._done + 1
            while self._done < due and self._running.is_set():
                self._on_tick(self._robot.step())
                self._done += 1

    def __enter__(self) -> "SimulatedModbusRobot":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the controller's cycle -------------------------------------------------------------------
    def _on_tick(self, state: SimState) -> None:
        self.program.cycle(state)
        self._ticks += 1
        if self._ticks % self._every == 0:
            self.image.write(state)

    def _on_write(self, table: str, address: int, values: list) -> None:
        """Log move and stop commands as the server receives them."""
        for name, kind in (("cmd_seq", "move"), ("stop_request", "stop")):
            e = self.map[name]
            if e.table == table and address <= e.address < address + len(values):
                if kind == "move" and "cmd_kind" in self.map:
                    if int(self.store.read_entry(self.map["cmd_kind"])[0]) == KIND_PAYLOAD:
                        kind = "payload"
                self.record_event(kind, f"{name}={values[e.address - address]}")

    # -- faults -----------------------------------------------------------------------------------
    def _sample_spans(self) -> list[tuple[str, int, int]]:
        return [(self.map[n].table, self.map[n].address, self.map[n].end) for n in SAMPLE_SIGNALS if n in self.map]

    def _apply_fault(self, name: str, params: dict[str, Any]) -> None:
        if name == "drop_connections":
            self.server.drop_connections(float(params.get("cut_s", 0.3)))
            self.active_faults.pop(name, None)  # a one-off event
        elif name == "stall_stream":
            self.image.stalled = True
        elif name == "garbage":
            if params.get("mode", "exception") == "exception":
                self.store.failing_reads = [(t, a, b, int(params.get("code", 4))) for t, a, b in self._sample_spans()]
            else:
                self.image.garbage = True
        elif name == "nan_values":
            self.image.nan = True
        elif name == "protective_stop":
            self._robot.trigger_protective_stop()
        elif name == "emergency_stop":
            self._robot.trigger_estop()
        elif name == "leave_remote":
            self.image.robot_mode_ok = False
            self.program.halt("the pendant took control")
        elif name == "slow_reply":
            self.store.reply_delay_s = float(params.get("delay_s", 0.3))
        elif name == "no_reply":
            self.server.drop_replies = True
        elif name == "never_finish":
            self.program.never_finish = True

    def _clear_fault(self, name: str) -> None:
        if name == "stall_stream":
            self.image.stalled = False
        elif name == "garbage":
            self.store.failing_reads = []
            self.image.garbage = False
        elif name == "nan_values":
            self.image.nan = False
        elif name in ("protective_stop", "emergency_stop", "leave_remote"):
            self._robot.reset_safety()
            self.image.robot_mode_ok = True
            self.program.start()
        elif name == "slow_reply":
            self.store.reply_delay_s = 0.0
        elif name == "no_reply":
            self.server.drop_replies = False
        elif name == "never_finish":
            self.program.never_finish = False

    # -- test and demo helpers --------------------------------------------------------------------
    def set_tool_change(self, value: int) -> None:
        self.image.tool_change = int(value)

    def set_digital_inputs(self, bits: int) -> None:
        self.image.digital_inputs = int(bits)

    def set_tcp_offset(self, position_m: Sequence[float], rotvec_rad: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        import numpy as np

        self.image.tcp_offset = (np.asarray(position_m, float), np.asarray(rotvec_rad, float))

    @property
    def payload_setting(self):
        return self.program.payload_setting

    def restart_program(self) -> None:
        self.program.start()

    def stop_program(self, reason: str = "stopped at the pendant") -> None:
        self.program.halt(reason)

    @property
    def tick_s(self) -> float:
        return self._robot.tick_s

    @staticmethod
    def update_period(regmap: RegisterMap) -> float:
        return 1.0 / (regmap.update_hz or DEFAULT_UPDATE_HZ)


