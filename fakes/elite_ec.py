"""Simulated Elite Robots EC controller (EC66): JSON-RPC on 8055, monitor frames on 8056.

It serves a ``SimRobot`` on loopback and is strict like the real controller, so a driver
that works against it has a fair chance of working against the robot:

* 8055: line-framed JSON-RPC 2.0, ``result`` always a JSON-encoded string
  (``elite_ec_rpc``), methods in ``elite_ec_methods``; motion and settings refused unless the
  robot is in remote mode (``set_mode(2)``), as the real controller only accepts them in remote
  mode (docs.elibot.cn "二次开发端口总结": 8055 commands need remote mode).
* 8056: a 1024-byte big-endian frame every 8 ms of simulated time (``elite_ec_monitor``),
  including the TCP and flange poses computed from the simulated arm's own DH table.

It implements the simulated-controller contract (fakes/base.py): ``from_config``,
``bound_options``, ``inject_fault`` with every common fault name, and ``events`` (every
accepted moveByJoint and every stop, with its receive time). Fault-side choices the public
sources do not settle: ``slow_reply`` delays every answer on every 8055 connection (the command
is executed on arrival); ``no_reply`` hangs the 8055 sessions open at that moment (their requests
are swallowed, neither executed nor answered) while a new connection is served, as a controller
that runs one handler per connection would; ``garbage`` sends 1024-byte blocks whose size field
announces no sensible frame; ``nan_values`` puts NaN in joint 2's angle and torque.

Test-side helpers: ``set_mode(0|1|2)``, ``press_estop()``, ``release_estop()``,
``trigger_collision()``, ``raise_alarm()``, ``set_servo()``, ``set_garbage_reply()``,
``set_digital_input()``, ``set_joint_temperatures()`` / ``joint_temperatures()``.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from payload_agent.fakes.base import FAULTS, SimulatedController, free_loopback_host, sim_robot_kwargs
from payload_agent.fakes.elite_ec_methods import (MODE_PLAY, MODE_REMOTE, MODE_TEACH, N_DIGITAL_INPUTS, N_TOOLS,
                                                  STATE_COLLISION, STATE_ERROR, STATE_ESTOP, STATE_RUNNING,
                                                  STATE_STOP, SUBTYPE_EC66, EliteMethods)
from payload_agent.fakes.elite_ec_models import (DEFAULT_JOINT_TEMPS_C, DEFAULT_STEADY_JOINT_TEMPS_C, FlangeFK,
                                                 JointThermal)
from payload_agent.fakes.elite_ec_monitor import PERIOD_S, MonitorServer, pack_frame
from payload_agent.fakes.elite_ec_pendant import ElitePendant
from payload_agent.fakes.elite_ec_rpc import INVALID_PARAMS, METHOD_NOT_FOUND, SERVER_ERROR, LineJsonRpcServer, RpcError
from payload_agent.fakes.hosted import HostedController
from payload_agent.fakes.sim_robot import SimRobot

if TYPE_CHECKING:
    from payload_agent.configuration.config import Config
    from payload_agent.drivers.base import DriverOptions

__all__ = ["FakeEliteController", "NOT_REMOTE_CODE", "MODE_TEACH", "MODE_PLAY", "MODE_REMOTE"]

# Refusal outside remote mode. UNVERIFIED: the public sources do not show what the real
# controller answers; we answer a JSON-RPC error in the implementation-defined range.
NOT_REMOTE_CODE = SERVER_ERROR
NOT_REMOTE_MESSAGE = "The robot is not in remote mode"

TICK_S = 0.008  # the simulated robot's tick: one monitor frame per tick
DEFAULT_SLOW_REPLY_S = 3.0
REQUEST_LOG_LIMIT = 10_000
GARBAGE_FRAME = b"GARBAGE!" * 128  # 1024 bytes whose first u32 announces no sensible frame size

# Methods that need remote mode.
_REMOTE_ONLY = {
    "moveByJoint", "cmd_set_payload", "set_servo_status", "syncMotorStatus", "clearAlarm",
    "setAutoRunToolNumber", "resetCollisionState",
}


def _sim_t(s) -> float:
    """The exact simulated time of a SimState (``t`` may carry the simulated timestamp jitter)."""
    t_true = getattr(s, "t_true", None)
    return s.t if t_true is None else t_true


class FakeEliteController(ElitePendant, EliteMethods, SimulatedController):
    faults = frozenset(FAULTS)

    def __init__(self, robot: SimRobot, host: str = "127.0.0.1", rpc_port: int = 8055, monitor_port: int = 8056,
                 rated_torque_nm: Sequence[float] | None = None, gain_error: Sequence[float] | None = None,
                 *, mode: int = MODE_REMOTE, soft_version: str = "3.5.2.sim", subtype: int = SUBTYPE_EC66,
                 max_payload_kg: float = 7.2, owns_robot: bool = False):
        super().__init__()
        self._robot = robot
        self._owns_robot = owns_robot  # from_config built it: start() and close() run it too
        self.host = host
        spec = robot.spec
        rated = rated_torque_nm if rated_torque_nm is not None else getattr(spec, "rated_torque_nm", (1.0,) * 6)
        self.rated_torque_nm = np.broadcast_to(np.asarray(rated, float), (6,)).copy()
        self.gain_error = np.broadcast_to(np.asarray(1.0 if gain_error is None else gain_error, float), (6,)).copy()
        # moveByJoint "speed"/"acc" are percentages of each joint's own maximum speed and
        # acceleration (as on the pendant); the synchronized PTP move then runs as fast as the
        # most constrained joint allows.
        self.joint_max_speed_rad_s = np.asarray(spec.max_speed_rad_s, float)
        self.joint_max_accel_rad_s2 = np.asarray(spec.max_accel_rad_s2, float)
        self.kinematics = FlangeFK(spec.dh)  # the simulated arm's own geometry: the poses it reports
        self.soft_version = soft_version
        self.subtype = int(subtype)
        self.max_payload_kg = float(max_payload_kg)

        self._lock = threading.RLock()
        self._mode = int(mode)
        self._estop_pressed = False
        self._alarm = False
        self._collision = False
        self._synced = True
        self._servo = bool(robot.snapshot().servo_on)  # commanded servo state (snapshots lag a tick)
        self._auto_tool = 0
        self._reset_t = -1.0  # sim time of the last successful clearAlarm
        self._payloads = [{"m": 0.0, "tool_cog": [0.0, 0.0, 0.0]} for _ in range(N_TOOLS)]
        self._inputs = [0] * N_DIGITAL_INPUTS  # X0..X63, set by tests with set_digital_input()
        self._thermal = JointThermal(DEFAULT_JOINT_TEMPS_C, DEFAULT_STEADY_JOINT_TEMPS_C)
        self._motion: dict | None = None  # {"t0", "dur", "seen"[, "stopped"]} while robotState is "running"
        self._next_frame_t: float | None = None
        self._garbage: dict[str, str] = {}
        self._pose_cache: tuple[bytes, list[float]] | None = None
        self.frames_sent = 0
        # the (method, params) received, for tests: the newest REQUEST_LOG_LIMIT at least (a soak of hundreds
        # of runs must not grow the process by the log of every poll)
        self.requests: list[tuple[str, Any]] = []

        self._rpc = LineJsonRpcServer(host, rpc_port, self._dispatch, name="elite-rpc",
                                      raw_override=self._raw_override)
        # 250 frames (2 s simulated) may wait behind a full socket buffer; beyond that the client holds
        # the simulation back (elastic time), so the stream never lags a fast simulation by seconds
        self._monitor = MonitorServer(host, monitor_port, max_queue=250)
        self._token: int | None = None
        self._started = False

    # -- the simulated-controller contract ----------------------------------------------------
    @classmethod
    def from_config(cls, config: "Config", *, in_process: bool = False) -> "FakeEliteController | HostedController":
        """A fake EC controller and its SimRobot from a robot YAML's ``simulation`` and ``driver`` sections,
        run in a process of its own (``fakes.hosted``), as the controller is a separate computer: served by
        threads of the agent's process, its 125 Hz stream stalled for over a second on a busy host, behind the
        agent's own threads. ``in_process`` builds it here (which is how that process builds it).

        Ports of 0 in the driver section mean ephemeral ports (see ``bound_options``); the host must be
        a loopback address (the TCP servers refuse any other), or ``auto``: a 127.0.0.x on which the
        ports are free.
        """
        from payload_agent.fakes.arms import simulated_spec

        sim = config.simulation
        if sim is None:
            raise ValueError("this config has no simulation section")
        if not in_process:
            return HostedController(f"{cls.__module__}:{cls.__name__}", config, cls.faults)
        spec = simulated_spec(sim)
        robot = SimRobot(spec, tick_s=TICK_S, **sim_robot_kwargs(config))
        opts = config.driver_options
        host = str(opts.host)
        if host == "auto":  # the real ports on a free 127.0.0.x, beside other simulations
            host = free_loopback_host([p for p in (int(opts.rpc_port), int(opts.monitor_port)) if p])
        return cls(robot, host=host, rpc_port=int(opts.rpc_port),
                   monitor_port=int(opts.monitor_port), rated_torque_nm=spec.rated_torque_nm,
                   gain_error=sim.drive_gain_error, owns_robot=True)

    def bound_options(self, options: "DriverOptions") -> "DriverOptions":
        return dataclasses.replace(options, host=self.host, rpc_port=self.rpc_port, monitor_port=self.monitor_port)

    @property
    def robot(self) -> SimRobot:
        return self._robot

    @property
    def rpc_port(self) -> int:
        return self._rpc.port

    @property
    def monitor_port(self) -> int:
        return self._monitor.port

    @property
    def rpc_connection_count(self) -> int:
        """How many clients are connected to the JSON-RPC port now."""
        return self._rpc.connection_count

    def start(self) -> "FakeEliteController":
        if not self._started:
            self._started = True
            if self._owns_robot:
                self._robot.start()
            self._token = self._robot.subscribe(self._on_tick)
            self._rpc.start()
            self._monitor.start()
        return self

    def close(self) -> None:
        if self._token is not None:
            self._robot.unsubscribe(self._token)
            self._token = None
        # both ports at once: each server's accept loop takes up to its poll interval to notice
        closer = threading.Thread(target=self._monitor.close, name="elite-monitor-close", daemon=True)
        closer.start()
        self._rpc.close()
        closer.join(timeout=5.0)
        if self._owns_robot:
            self._robot.close()

    def __enter__(self) -> "FakeEliteController":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _apply_fault(self, name: str, params: dict[str, Any]) -> None:
        if name == "drop_connections":
            self._rpc.drop_connections()
            self._monitor.drop_connections()
            self.active_faults.pop(name, None)  # a one-off event: new connections are served again
        elif name == "protective_stop":
            self.trigger_collision()
        elif name == "emergency_stop":
            self.press_estop()
        elif name == "leave_remote":
            self.set_mode(MODE_TEACH)
        elif name == "slow_reply":
            self._rpc.reply_delay_s = float(params.get("delay_s", DEFAULT_SLOW_REPLY_S))
        elif name == "no_reply":
            self._rpc.hang_connections()
        # stall_stream, garbage, nan_values, never_finish act through active_faults (see _on_tick)

    def _clear_fault(self, name: str) -> None:
        if name == "slow_reply":
            self._rpc.reply_delay_s = 0.0
        elif name == "no_reply":
            self._rpc.unhang_connections()

    # -- test-side helpers (the pendant's and the cell's controls: fakes/elite_ec_pendant.py) ------------
    def set_garbage_reply(self, method: str, raw_line: str | None) -> None:
        """Answer ``method`` with this raw line (without newline) instead of a proper reply."""
        with self._lock:
            if raw_line is None:
                self._garbage.pop(method, None)
            else:
                self._garbage[method] = raw_line

    def payload_setting(self, tool_num: int = 0) -> dict:
        with self._lock:
            p = self._payloads[tool_num]
            return {"m": p["m"], "tool_cog": list(p["tool_cog"])}

    @property
    def mode(self) -> int:
        return self._mode

    def robot_state(self) -> int:
        return self._robot_state(self._robot.snapshot())

    # -- state --------------------------------------------------------------------------------
    def _robot_state(self, s) -> int:
        with self._lock:
            if self._estop_pressed:
                return STATE_ESTOP
            if self._collision:
                return STATE_COLLISION
            # the sim's own safety flags count too (set directly on the SimRobot), except in a
            # snapshot taken before the last clearAlarm (snapshots lag up to one tick)
            if self._alarm or ((s.estop or s.protective_stop) and _sim_t(s) > self._reset_t):
                return STATE_ERROR
            if self._motion is not None:
                return STATE_RUNNING
            return STATE_STOP

    def _mark_motion_stopped(self) -> None:
        """The running motion was stopped: robotState leaves "running" once the arm stands (see _on_tick)."""
        with self._lock:
            if self._motion is not None:
                self._motion["stopped"] = True

    def _effort_pct(self, torque_nm: np.ndarray) -> np.ndarray:
        # percent of rated torque, with the drive's gain error (current -> torque)
        return np.asarray(torque_nm, float) / self.rated_torque_nm * 100.0 * self.gain_error

    def _flange_pose(self, q: np.ndarray) -> list[float]:
        """The flange pose in Elite units (mm, rad) from the simulated arm's DH table (cached per q)."""
        key = np.asarray(q, float).tobytes()
        cached = self._pose_cache
        if cached is not None and cached[0] == key:
            return list(cached[1])
        pose = self.kinematics.elite_pose(np.asarray(q, float).tolist())
        self._pose_cache = (key, pose)
        return list(pose)

    def _on_tick(self, s) -> None:
        t = _sim_t(s)
        with self._lock:
            self._thermal.advance(t)
            m = self._motion
            if m is not None:
                if s.moving:
                    m["seen"] = True
                elif m.get("stopped") or (m["seen"] or t >= m["t0"] + m["dur"] - 1e-9) and \
                        "never_finish" not in self.active_faults:
                    self._motion = None
            if self._next_frame_t is None:
                self._next_frame_t = (math.floor(t / PERIOD_S + 1e-9)) * PERIOD_S
            due = t >= self._next_frame_t - 1e-9
            if due:
                # one frame per 8 ms grid point (sample and hold if the tick is coarser)
                while self._next_frame_t <= t + 1e-9:
                    self._next_frame_t += PERIOD_S
        if not due or "stall_stream" in self.active_faults or not self._monitor.has_clients():
            return
        self._monitor.broadcast(GARBAGE_FRAME if "garbage" in self.active_faults else self._frame(s))
        self.frames_sent += 1

    def _frame(self, s) -> bytes:
        pct = self._effort_pct(s.torque_nm)
        q_deg = list(np.degrees(s.q))
        if "nan_values" in self.active_faults:
            q_deg[1] = pct[1] = float("nan")
        pose = self._flange_pose(s.q)  # the fake's tools have no TCP offset: TCP pose = flange pose
        with self._lock:
            values = {
                "TimeStamp": int(round(s.t * 1000.0)),  # the reported (possibly jittered) time
                "autorun_cycleMode": 2,
                "machinePos": q_deg + [0.0, 0.0],
                "machinePose": pose, "machineUserPose": pose,
                "torque": list(pct) + [0.0, 0.0],
                "robotState": self._robot_state(s),
                "servoReady": 1 if s.servo_on else 0,
                "can_motor_run": 1 if self._synced else 0,
                "robotMode": self._mode,
                "collision": 1 if self._collision else 0,
                "machineFlangePose": pose, "machineUserFlangePose": pose,
                "emergencyStopState": 1 if self._estop_pressed else 0,
                "digital_ioInput": sum(1 << i for i, v in enumerate(self._inputs) if v),
                "joint_speed": list(np.degrees(s.qd)) + [0.0, 0.0],
                "jointacc": list(np.degrees(s.qdd)) + [0.0, 0.0],
                "joint_temperature": [float(v) for v in self._thermal.value],
                "jointTorque": list(np.asarray(s.torque_nm, float)),
            }
        return pack_frame(values)

    # -- JSON-RPC -----------------------------------------------------------------------------
    def _raw_override(self, method: str) -> str | None:
        with self._lock:
            return self._garbage.get(method)

    def _dispatch(self, method: str, params: Any) -> Any:
        with self._lock:
            self.requests.append((method, params))
            if len(self.requests) > 2 * REQUEST_LOG_LIMIT:
                del self.requests[:REQUEST_LOG_LIMIT]
        fn = getattr(self, "_m_" + method, None)
        if fn is None:
            raise RpcError(METHOD_NOT_FOUND, "Method not found")
        if params is None or params == []:
            params = {}
        if not isinstance(params, dict):
            raise RpcError(INVALID_PARAMS, "Invalid params: params must be an object")
        if method in _REMOTE_ONLY and self._mode != MODE_REMOTE:
            raise RpcError(NOT_REMOTE_CODE, NOT_REMOTE_MESSAGE)
        return fn(params)
