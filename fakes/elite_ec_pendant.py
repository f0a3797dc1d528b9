"""The simulated EC controller's physical side: what a person at the cell does to it.

The pendant's mode key, the emergency-stop button, a collision or a drive alarm, the servo power,
the cabinet's digital inputs and the joints' temperatures. Tests and the fault matrix use these to
put the controller in the states a real cell gets into; the protocol side (``elite_ec.py``) then
reports them as the real controller would. A mixin of ``FakeEliteController``, whose state it sets.
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Sequence

from payload_agent.fakes.elite_ec_methods import MODE_PLAY, MODE_REMOTE, MODE_TEACH, N_DIGITAL_INPUTS
from payload_agent.fakes.elite_ec_models import JointThermal
from payload_agent.fakes.sim_robot import SimRobot


class ElitePendant:
    """Set-up of the controller's state from outside the protocol (all under the controller's lock)."""

    _lock: threading.RLock
    _robot: SimRobot
    _mode: int
    _estop_pressed: bool
    _alarm: bool
    _collision: bool
    _servo: bool
    _inputs: Any
    _thermal: JointThermal
    _mark_motion_stopped: Callable[[], None]  # the controller's: the running motion was stopped

    def set_mode(self, mode: int) -> None:
        """Turn the pendant's mode key: 0 teach, 1 play, 2 remote. Leaving remote stops motion."""
        if mode not in (MODE_TEACH, MODE_PLAY, MODE_REMOTE):
            raise ValueError("mode must be 0, 1 or 2")
        with self._lock:
            if mode != MODE_REMOTE and self._mode == MODE_REMOTE:
                self._robot.stop()
                self._mark_motion_stopped()
            self._mode = mode

    def press_estop(self) -> None:
        with self._lock:
            self._estop_pressed = True
            self._alarm = True
            self._robot.trigger_estop()
            self._robot.set_servo(False)
            self._servo = False
            self._mark_motion_stopped()

    def release_estop(self) -> None:
        """The button is released; the alarm stays until clearAlarm, servos stay off."""
        with self._lock:
            self._estop_pressed = False

    def trigger_collision(self) -> None:
        with self._lock:
            self._collision = True
            self._robot.trigger_protective_stop()
            self._mark_motion_stopped()

    def raise_alarm(self) -> None:
        """Any servo/controller alarm: robotState 4 until clearAlarm."""
        with self._lock:
            self._alarm = True
            self._robot.trigger_protective_stop()
            self._mark_motion_stopped()

    def set_servo(self, on: bool) -> None:
        with self._lock:
            self._robot.set_servo(on)
            self._servo = bool(on)
            if not on:
                self._mark_motion_stopped()

    def set_digital_input(self, index: int, value: bool | int) -> None:
        """Drive the controller's digital input X<index> (0..63) high (1/True) or low (0/False)."""
        if not isinstance(index, int) or isinstance(index, bool) or not (0 <= index < N_DIGITAL_INPUTS):
            raise ValueError(f"digital input index must be an integer in [0, {N_DIGITAL_INPUTS - 1}], got {index!r}")
        with self._lock:
            self._inputs[index] = 1 if value else 0

    def set_joint_temperatures(self, values: Sequence[float], steady: Sequence[float] | None = None) -> None:
        """Set the joints' temperatures (6 values, °C), shown from the next monitor frame on.

        They then stay put, or, with ``steady``, drift towards it with the fake's 30-minute time
        constant (simulated time).
        """
        with self._lock:
            self._thermal.set(values, steady)

    def joint_temperatures(self) -> tuple[float, ...]:
        """The joints' temperatures (°C) the controller reports now."""
        with self._lock:
            return tuple(float(v) for v in self._thermal.value)
