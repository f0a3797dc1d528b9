"""A minimal driver and simulated controller for a trivial in-process arm (docs/drivers.md): the
"protocol" is a queue of a SimRobot's states; the base class does stream, statistics and supervision."""

from __future__ import annotations

import dataclasses
import queue
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from payload_agent.drivers.base import DONE, RUNNING, Driver, DriverOptions, MoveStatus, aborted, option
from payload_agent.errors import CommunicationError
from payload_agent.fakes.base import SimulatedController, sim_robot_kwargs
from payload_agent.types import ControllerInfo, ControllerState, Sample

CONTROLLERS: dict[str, "InProcessController"] = {}  # the "network": controllers by name


@dataclass(frozen=True, kw_only=True)
class InProcessOptions(DriverOptions):
    name: str = option(help="which in-process controller to talk to")


class InProcessDriver(Driver):
    name = "inproc"
    options_class = InProcessOptions
    simulator = "inproc_driver:InProcessController"

    def __init__(self, options, limits, supervision=None):
        super().__init__(options, limits, supervision)
        self.effort_unit, self.nominal_period_s = "Nm", 0.008
        self._ctrl: InProcessController | None = None
        self._states: queue.Queue = queue.Queue()

    def _open(self) -> None:
        self._ctrl = CONTROLLERS.get(self.options.name)
        if self._ctrl is None:
            raise CommunicationError(f"no in-process controller named {self.options.name!r}")
        self._token = self._ctrl.robot.subscribe(self._states.put)

    def _close(self) -> None:
        self._ctrl.robot.unsubscribe(self._token)

    def _read_sample(self, timeout_s: float) -> Sample | None:
        try:
            s = self._states.get(timeout=timeout_s)
        except queue.Empty:
            return None
        return Sample(float(s.t), time.monotonic(), tuple(map(float, s.q)), tuple(map(float, s.torque_nm)))

    def identify(self) -> ControllerInfo:
        return ControllerInfo("test", "in-process arm", "1.0")

    def state(self) -> ControllerState:
        s = self._ctrl.robot.snapshot()
        if s.estop or s.protective_stop:
            return ControllerState(False, "clear the stop on the simulated robot", s.estop, s.protective_stop)
        return ControllerState(True, moving=s.moving)

    def _prepare_move(self, target, speed_rad_s, accel_rad_s2) -> None:
        pass  # this arm takes any move; the status says when it stops short

    def _start_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> MoveStatus | None:
        robot = self._ctrl.robot
        self._ctrl.record_event("move")
        self._before, self._target = robot.snapshot().move_id, target
        robot.move_joints(target, speed_rad_s, accel_rad_s2)
        return None

    def _move_status(self) -> MoveStatus:
        s = self._ctrl.robot.snapshot()
        if s.move_id == self._before or s.moving:
            return RUNNING
        if s.estop or s.protective_stop or np.max(np.abs(s.q - self._target)) > 1e-3:
            return aborted("the move ended away from its target (stopped)")
        return DONE

    def _stop_command(self) -> bool:
        self._ctrl.record_event("stop")
        self._ctrl.robot.stop()
        return True


class InProcessController(SimulatedController):
    faults = frozenset({"protective_stop", "stall_stream"})

    def __init__(self, name: str, robot):
        super().__init__()
        self.name, self._robot = name, robot

    @classmethod
    def from_config(cls, config) -> "InProcessController":
        from payload_agent.fakes.arms import SPECS
        from payload_agent.fakes.sim_robot import SimRobot

        robot = SimRobot(SPECS[config.simulation.arm](), tick_s=0.008, **sim_robot_kwargs(config))
        return cls(config.driver_options.name, robot)

    @property
    def robot(self) -> Any:
        return self._robot

    def start(self) -> "InProcessController":
        CONTROLLERS[self.name] = self
        self._robot.start()
        return self

    def close(self) -> None:
        CONTROLLERS.pop(self.name, None)
        self._robot.close()

    def bound_options(self, options):
        return dataclasses.replace(options)

    def _apply_fault(self, name: str, params: dict) -> None:
        if name == "protective_stop":
            self._robot.trigger_protective_stop()
        else:  # stall_stream: the robot keeps moving, its states stop reaching anyone
            self._robot._subscribers.clear()
