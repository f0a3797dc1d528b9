"""The simulated UR e-Series controller itself, in the current process.

It owns the controller state (modes, registers, payload setting, TCP, digital inputs, joint
temperatures), runs one control cycle per tick of the ``SimRobot`` clock (``_on_tick``: builds
the ``Snapshot`` every RTDE session sends from), and serves on one loopback address:

- 30004 RTDE (``rtde_session``), 29999 dashboard (``dashboard``),
- 30001/30002/30003 script ports (``programs``: ur_rtde's control script or plain URScript).

``FakeURController`` (``process``) hosts it in a child process, because ur_rtde's Python
constructors hold the GIL while they wait for the controller.
"""

from __future__ import annotations

import collections
import math
import socket
import threading
import time
from typing import Any, Callable, Sequence

import numpy as np

from payload_agent.fakes.base import ControllerEvent
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot, SimState
from payload_agent.fakes.tcp_server import TCPServer, shutdown_socket
from payload_agent.fakes.ur.constants import (DASHBOARD_PORT, DEFAULT_CURRENT_NOISE_A, DEFAULT_GAINS_NM_PER_A,
                                              DEFAULT_JOINT_TEMPS_C, DEFAULT_STEADY_JOINT_TEMPS_C,
                                              DEFAULT_TCP_OFFSET, JOINT_TEMP_TAU_S, N_DIGITAL_INPUTS,
                                              ROBOT_MODE_POWER_OFF, ROBOT_MODE_RUNNING, RTDE_PORT,
                                              RUNTIME_STOPPED, SAFETY_MODE_NORMAL,
                                              SAFETY_MODE_PROTECTIVE_STOP, SAFETY_MODE_ROBOT_EMERGENCY_STOP,
                                              SCRIPT_PORTS, SSB_ESTOP, SSB_NORMAL, SSB_PROTECTIVE, SSB_ROBOT_ESTOP,
                                              SSB_STOPPED_BY_SAFETY, UR5E_HOME_Q, pick_loopback_host)
from payload_agent.fakes.ur.dashboard import serve_dashboard
from payload_agent.fakes.ur.faults import FaultState
from payload_agent.fakes.ur.outputs import TcpPose, build_snapshot
from payload_agent.fakes.ur.own_model import ControllerModel, configured_payload
from payload_agent.fakes.ur.programs import ProgramHost
from payload_agent.fakes.ur.rtde_session import RTDESession

_NAN6 = np.full(6, np.nan)


class URControllerCore:
    """The controller, in the current process (``FakeURController`` hosts it in a child process)."""

    def __init__(self, host: str | None = None, sim: SimRobot | None = None, *, spec=None,
                 q0_rad: Sequence[float] = UR5E_HOME_Q, time_scale: float = 1.0, tick_s: float = 0.002,
                 gains_nm_per_a: Sequence[float] = DEFAULT_GAINS_NM_PER_A,
                 current_noise_a: float | Sequence[float] = DEFAULT_CURRENT_NOISE_A, seed: int | None = 0,
                 payload: PayloadTruth | None = None, friction: FrictionParams | None = None,
                 noise_nm: float | Sequence[float] = 0.0, gain_error: float | Sequence[float] = 1.0,
                 sim_options: dict[str, Any] | None = None,
                 controller_version: tuple[int, int, int, int] = (5, 11, 1, 108318),
                 serial_number: str = "20215300042", robot_model: str = "UR5",
                 remote_control: bool = True, max_payload_kg: float = 5.0,
                 tcp_offset: Sequence[float] = DEFAULT_TCP_OFFSET, ports: dict[str, int] | None = None,
                 keep_payload_inertia: bool = False, script_start_delay_s: float = 0.0):
        self._own_sim = sim is None
        if sim is None:
            from payload_agent.fakes.arms import ur5e_spec

            sim = SimRobot(spec or ur5e_spec(), q0_rad=q0_rad, tick_s=tick_s, time_scale=time_scale,
                           friction=friction, noise_nm=noise_nm, seed=seed, payload=payload, **(sim_options or {}))
        self.robot: SimRobot = sim
        self.host = host
        self.log: collections.deque[str] = collections.deque(maxlen=2000)
        self.gains = np.broadcast_to(np.asarray(gains_nm_per_a, float), (6,)).copy()
        # multiplicative drive-gain error per joint (1.0 = the drive reports exactly torque / gain)
        self.gain_error = np.broadcast_to(np.asarray(gain_error, float), (6,)).copy()
        self.current_noise_a = np.broadcast_to(np.asarray(current_noise_a, float), (6,)).copy()
        self._rng = np.random.default_rng(None if seed is None else seed + 7919)
        self.controller_version = tuple(int(v) for v in controller_version)
        self.serial_number = serial_number
        self.robot_model = robot_model
        self.remote_control = remote_control
        self.max_payload_kg = float(max_payload_kg)
        self.keep_payload_inertia = bool(keep_payload_inertia)  # inertia writes ignored: a readback mismatch
        # how long a control script runs (PLAYING) before its first register write: until then the output
        # registers still hold the previous program's values, as on a real controller
        self.script_start_delay_s = float(script_start_delay_s)
        self.max_frequency_hz = 500.0 if self.controller_version[0] >= 5 else 125.0
        ports = dict(ports or {})
        self.rtde_port = ports.get("rtde", RTDE_PORT)
        self.dashboard_port = ports.get("dashboard", DASHBOARD_PORT)
        self.script_ports = tuple(ports.get(k, p) for k, p in zip(("primary", "secondary", "realtime"), SCRIPT_PORTS))

        self.lock = threading.RLock()
        self.out_int = [0] * 48
        self.out_dbl = [0.0] * 48
        self.in_int = [0] * 48
        self.in_dbl = [0.0] * 48
        self.out_bits = 0
        self.in_bits = 0
        self.digital_in = 0  # actual_digital_input_bits: 0-7 DI, 8-15 CI, 16-17 tool inputs (RTDE guide)
        self._temps = np.asarray(DEFAULT_JOINT_TEMPS_C, float)  # joint_temperatures, °C
        self._temps_steady = np.asarray(DEFAULT_STEADY_JOINT_TEMPS_C, float)
        self._temps_t: float | None = None
        self.inputs_misc: dict[str, Any] = {}
        self.input_owner: dict[str, object] = {}
        self.robot_mode = ROBOT_MODE_RUNNING
        self.runtime_state = RUNTIME_STOPPED
        self.payload_mass = 0.0
        self.payload_cog = (0.0, 0.0, 0.0)
        self.payload_inertia = (0.0,) * 6
        self.tcp_offset: tuple[float, ...] = ()
        self.set_tcp_offset(tcp_offset)
        self.own_model = ControllerModel(self.robot.spec, self.gains, seed)  # target_moment / target_current
        self._kin = None

        self.script_errors: list[str] = []
        self.rtde_errors: list[str] = []
        self.rtde_sessions: list[RTDESession] = []
        self.events: list[ControllerEvent] = []  # every move / stop command accepted (fakes.base contract)
        self.faults = FaultState(self)
        self.programs = ProgramHost(self)
        self._tick_cv = threading.Condition()
        self._tick = 0
        self._last_safety = (False, False)
        self.protective_since: float | None = None
        self._sub_token: int | None = None
        self._servers: list[TCPServer] = []
        self._conns: set[socket.socket] = set()
        self.closing = threading.Event()
        self._started = False

    # -- lifecycle --------------------------------------------------------------------------------
    def start(self) -> "URControllerCore":
        if self._started:
            return self
        attempts = 1 if self.host is not None else 8
        for attempt in range(attempts):
            host = self.host if attempts == 1 else pick_loopback_host()
            try:
                for port, handler in ((self.rtde_port, self._serve_rtde),
                                      (self.dashboard_port, lambda conn: serve_dashboard(self, conn)),
                                      *((p, self.programs.serve_script) for p in self.script_ports)):
                    self._listen(host, port, handler)
                self.host = host
                break
            except OSError:
                self._close_listeners()
                if attempt == attempts - 1:
                    raise
        self._sub_token = self.robot.subscribe(self._on_tick)
        if self.robot._thread is None:  # noqa: SLF001 - start the clock if nobody did
            self.robot.start()
        self._started = True
        self.note(f"controller up on {self.host}")
        return self

    def close(self) -> None:
        self.closing.set()
        self.programs.stop_program("controller shut down", wait=True)
        if self._sub_token is not None:
            self.robot.unsubscribe(self._sub_token)
            self._sub_token = None
        for sess in list(self.rtde_sessions):
            sess.close()
        self._close_listeners()
        if self._own_sim:
            self.robot.close()
        self._started = False

    def __enter__(self) -> "URControllerCore":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _listen(self, host: str, port: int, handler: Callable[[socket.socket], None]) -> None:
        def tracked(conn: socket.socket, addr) -> None:
            with self.lock:
                self._conns.add(conn)
            try:
                handler(conn)
            finally:
                with self.lock:
                    self._conns.discard(conn)

        server = TCPServer(host, port, tracked, name=f"ur-fake-{port}", on_error=self.note)
        self._servers.append(server.start())

    def _close_listeners(self) -> None:
        servers, self._servers = self._servers, []
        for server in servers:  # stops accepting, shuts every connection down, joins the handlers
            server.close()

    def drop_connections(self) -> None:
        """Shut down every open client connection; the ports keep listening."""
        with self.lock:
            conns = list(self._conns)
        for conn in conns:
            shutdown_socket(conn)

    def note(self, text: str) -> None:
        self.log.append(f"{self.robot.now():10.3f} {text}")

    def record_event(self, kind: str, detail: str = "") -> None:
        with self.lock:
            self.events.append(ControllerEvent(time.monotonic(), kind, detail))

    # -- test-side state changes -------------------------------------------------------------------
    def trigger_protective_stop(self) -> None:
        """As if the arm had hit something: motion stops, the program is stopped."""
        self.robot.trigger_protective_stop()

    def trigger_estop(self) -> None:
        """Emergency stop button: motion stops, the arm powers off."""
        self.robot.trigger_estop()

    def release_estop(self) -> None:
        """Release the e-stop; the arm stays off until 'power on' + 'brake release' (dashboard). The
        simulation has one reset for both stops: a pending protective stop is cleared too."""
        self.robot.reset_safety()

    def reset_safety(self) -> None:
        """Clear every stop and bring the arm back to RUNNING (test convenience)."""
        with self.lock:
            self.robot.reset_safety()
            self.protective_since = None
            self.robot_mode = ROBOT_MODE_RUNNING
            self.robot.set_servo(True)

    def set_remote_control(self, on: bool) -> None:
        self.remote_control = bool(on)

    def set_digital_input(self, index: int, value: bool) -> None:
        """Drive digital input ``index`` (bit of actual_digital_input_bits: 0-7 DI0-7, 8-15 CI0-7,
        16-17 tool TI0-1) high or low; RTDE shows it from the next control cycle on."""
        if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < N_DIGITAL_INPUTS:
            raise ValueError(f"digital input index must be an integer in [0, {N_DIGITAL_INPUTS - 1}], got {index!r}")
        with self.lock:
            self.digital_in = (self.digital_in | (1 << index)) if value else (self.digital_in & ~(1 << index))

    def set_joint_temperatures(self, values: Sequence[float], steady: Sequence[float] | None = None) -> None:
        """Set RTDE joint_temperatures (6 values, °C) from the next control cycle on; they then stay put,
        or, with ``steady``, drift towards it with a 30-minute time constant (simulated time)."""
        def check(v, what):
            v = list(v)
            if len(v) != 6 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                                      and -40.0 <= x <= 200.0 for x in v):
                raise ValueError(f"{what} must be 6 numbers in [-40, 200] °C, got {v!r}")
            return np.asarray(v, float)

        temps = check(values, "joint temperatures")
        target = temps.copy() if steady is None else check(steady, "steady joint temperatures")
        with self.lock:
            self._temps, self._temps_steady = temps, target

    def set_tcp_offset(self, pose: Sequence[float]) -> None:
        """The installation's TCP, [x, y, z, rx, ry, rz] in the flange frame (m, rotation vector)."""
        values = [float(v) for v in pose]
        if len(values) != 6 or not all(math.isfinite(v) for v in values) or max(map(abs, values[:3])) > 1.0:
            raise ValueError(f"set_tcp: a TCP is 6 finite values, position within 1 m, got {list(pose)!r}")
        with self.lock:
            self.tcp_offset = tuple(values)
        self.note(f"tcp set: {self.tcp_offset}")

    @property
    def joint_temperatures(self) -> tuple[float, ...]:
        with self.lock:
            return tuple(float(v) for v in self._temps)

    @property
    def controller_payload(self) -> tuple[float, tuple[float, float, float]]:
        with self.lock:
            return self.payload_mass, self.payload_cog

    # -- registers and settings used by sessions and programs ---------------------------------------
    def read_input_register(self, kind: str, index: int) -> Any:
        with self.lock:
            return (self.in_int if kind == "int" else self.in_dbl)[index]

    def write_output_register(self, kind: str, index: int, value: Any) -> None:
        with self.lock:
            (self.out_int if kind == "int" else self.out_dbl)[index] = value

    def set_payload_setting(self, mass: float, cog: Sequence[float] | None,
                            inertia: Sequence[float] | None = None) -> None:
        """set_payload / set_target_payload: the payload the controller's own model uses."""
        from payload_agent.fakes.ur.urscript import ProgramError, check_target_payload_inertia

        if not math.isfinite(mass) or mass < 0 or mass > self.max_payload_kg:
            raise ProgramError(f"set_payload: mass {mass} kg outside [0, {self.max_payload_kg}] kg")
        if inertia is not None:
            check_target_payload_inertia(inertia)  # as the real script's runtime error
        with self.lock:
            self.payload_mass = float(mass)
            if cog is not None:
                self.payload_cog = tuple(float(c) for c in cog)
            if inertia is None or not self.keep_payload_inertia:
                self.payload_inertia = tuple(float(v) for v in inertia) if inertia is not None else (0.0,) * 6
            self.own_model.set_payload(configured_payload(self.payload_mass, self.payload_cog, self.payload_inertia))
        self.record_event("payload", f"{self.payload_mass} kg at {self.payload_cog}")
        self.note(f"payload set: {self.payload_mass} kg at {self.payload_cog}")

    def stop_program(self, reason: str, wait: bool) -> bool:
        return self.programs.stop_program(reason, wait)

    @property
    def program_name(self) -> str:
        return self.programs.program_name

    # -- derived quantities ------------------------------------------------------------------------
    def tcp_pose(self, q: Sequence[float], tcp_offset: Sequence[float]) -> tuple[float, ...]:
        """actual_TCP_pose: the flange pose of the simulated kinematics times the TCP offset."""
        if not all(math.isfinite(v) for v in q):
            return tuple(_NAN6)
        if self._kin is None:
            self._kin = TcpPose(self.robot.spec.dh)
        return self._kin.pose(q, tcp_offset)

    def safety(self, st: SimState) -> tuple[int, int]:
        """(safety_mode, safety_status_bits) of a simulation state."""
        if st.estop:
            return SAFETY_MODE_ROBOT_EMERGENCY_STOP, (1 << SSB_ROBOT_ESTOP) | (1 << SSB_ESTOP) | (1 << SSB_STOPPED_BY_SAFETY)
        if st.protective_stop:
            return SAFETY_MODE_PROTECTIVE_STOP, (1 << SSB_PROTECTIVE) | (1 << SSB_STOPPED_BY_SAFETY)
        return SAFETY_MODE_NORMAL, 1 << SSB_NORMAL

    # -- the control cycle (sim clock thread) ---------------------------------------------------
    def _on_tick(self, st: SimState) -> None:
        safety = (bool(st.estop), bool(st.protective_stop))
        if safety != self._last_safety:
            self._on_safety_change(safety)
            self._last_safety = safety
        current = st.torque_nm / self.gains * self.gain_error + self._rng.normal(0.0, 1.0, 6) * self.current_noise_a
        s = build_snapshot(self, st, current, nan=self.faults.is_active("nan_values"))
        with self.lock:
            sessions = list(self.rtde_sessions)
        for sess in sessions:
            sess.on_tick(s)
        with self._tick_cv:
            self._tick += 1
            self._tick_cv.notify_all()

    def advance_temperatures(self, t: float) -> tuple[float, ...]:
        """joint_temperatures at simulated time ``t`` (first-order lag towards the steady values)."""
        with self.lock:
            if self._temps_t is not None and t > self._temps_t:
                self._temps = self._temps + (self._temps_steady - self._temps) * \
                    (1.0 - math.exp(-(t - self._temps_t) / JOINT_TEMP_TAU_S))
            self._temps_t = t
            return tuple(float(v) for v in self._temps)

    def _on_safety_change(self, safety: tuple[bool, bool]) -> None:
        estop, protective = safety
        if estop:
            self.note("safety: robot emergency stop")
            with self.lock:
                self.robot_mode = ROBOT_MODE_POWER_OFF  # the arm loses power; the sim brakes it
            self.stop_program("emergency stop", wait=False)
        elif protective:
            self.note("safety: protective stop")
            self.protective_since = self.robot.now()
            self.stop_program("protective stop", wait=False)
        else:
            self.note("safety: normal")

    def wait_ticks(self, n: int = 1, timeout: float = 5.0) -> None:
        """Block until ``n`` more control cycles have run (tests and programs)."""
        with self._tick_cv:
            target = self._tick + n
            self._tick_cv.wait_for(lambda: self._tick >= target or self.closing.is_set(), timeout)

    def wait_next_tick(self, cancelled: Callable[[], bool]) -> None:
        """Block until the next control cycle, ``cancelled()`` or shut-down (URScript sync())."""
        with self._tick_cv:
            start = self._tick
            while self._tick == start and not cancelled() and not self.closing.is_set():
                self._tick_cv.wait(0.05)

    # -- RTDE server ----------------------------------------------------------------------------------
    def _serve_rtde(self, conn: socket.socket) -> None:
        sess = RTDESession(self, conn)
        with self.lock:
            self.rtde_sessions.append(sess)
        try:
            sess.serve()
        finally:
            sess.close()
            with self.lock:
                if sess in self.rtde_sessions:
                    self.rtde_sessions.remove(sess)
                for name, owner in list(self.input_owner.items()):
                    if owner is sess:
                        del self.input_owner[name]
