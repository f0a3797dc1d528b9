"""The robot-side handshake program, run by the simulated controller once per control cycle.

It does what procedures/ur_modbus_handshake.script does on a UR controller (docs/modbus.md):
poll ``stop_request`` and ``cmd_seq`` every cycle, take a new command (move or set payload),
answer ``status``/``error_code`` and then ``ack_seq``, acknowledge a stop in ``stop_ack`` after
telling the arm to stop, and count ``heartbeat``. Like a program on a real controller it halts
on a protective or emergency stop (and when the pendant takes control back): from then on
nothing answers until it is started again.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from payload_agent.drivers.modbus import handshake as hs
from payload_agent.drivers.modbus.registers import int_range
from payload_agent.drivers.modbus.regmap import RegisterMap, si_factor
from payload_agent.fakes.modbus.store import RegisterStore
from payload_agent.fakes.sim_robot import SimRefused, SimRobot, SimState

TARGET_TOLERANCE_RAD = 0.005  # the program's own "arrived" check, as in the URScript program
MAX_ABS_TARGET_RAD = 2 * math.pi


class HandshakeProgram:
    """One instance per simulated controller; ``cycle(state)`` is called every tick of the robot's clock."""

    def __init__(self, store: RegisterStore, regmap: RegisterMap, robot: SimRobot,
                 record_event: Callable[[str, str], None]):
        self.store = store
        self.map = regmap
        self.robot = robot
        self.record_event = record_event
        self.running = False
        self.halt_reason = ""
        self.never_finish = False  # fault: the move ends but the program never says so
        self.payload_setting: tuple[float, tuple[float, float, float]] | None = None
        self._last_seq = 0
        self._last_stop = 0
        self._beat = 0
        self._busy_seq: int | None = None
        self._move_id: int | None = None
        self._target: np.ndarray | None = None
        self._max_speed = float(np.max(robot.spec.max_speed_rad_s))
        self._max_accel = float(np.max(robot.spec.max_accel_rad_s2))

    def _get(self, name: str) -> list[float]:
        return self.store.read_entry(self.map[name])

    def _int(self, name: str) -> int:
        return int(round(self._get(name)[0]))

    def _put(self, name: str, values) -> None:
        if name in self.map:
            self.store.write_entry(self.map[name], values)

    def answer(self, status: int, seq: int, code: int = 0) -> None:
        self._put("error_code", [code])
        self._put("status", [status])
        self._put("ack_seq", [seq])  # last: an ack_seq always comes with its own status

    # -- program life ---------------------------------------------------------------------------
    def start(self) -> None:
        """Start (or restart) the program: commands already in the registers are not taken."""
        self._last_seq = self._int("cmd_seq")
        self._last_stop = self._int("stop_request")
        self._put("stop_ack", [self._last_stop])
        self._busy_seq = None
        self._move_id = None
        self.answer(hs.STATUS_IDLE, self._last_seq)
        self.running = True
        self.halt_reason = ""

    def halt(self, reason: str) -> None:
        """The program stops (pendant, safety stop); a move it started is stopped by the controller."""
        if self.running:
            self.running = False
            self.halt_reason = reason
            self.robot.stop()

    # -- one control cycle --------------------------------------------------------------------------
    def cycle(self, state: SimState) -> None:
        if not self.running:
            return
        if state.protective_stop or state.estop:
            self.halt("protective stop" if state.protective_stop else "emergency stop")
            return
        self._beat = (self._beat + 1) % (int_range(self.map["heartbeat"].type)[1] + 1
                                         if "heartbeat" in self.map else 65536)
        self._put("heartbeat", [self._beat])
        stop = self._int("stop_request")
        if stop != self._last_stop:
            self._stop(stop)
        if self._busy_seq is not None and state.move_id == self._move_id and not state.moving:
            self._finish(state)
        seq = self._int("cmd_seq")
        if seq != self._last_seq and seq != 0:
            self._last_seq = seq
            self._take(seq, state)

    def _stop(self, value: int) -> None:
        self._last_stop = value
        if self._busy_seq is not None:
            self.robot.stop()
            self.answer(hs.STATUS_ERROR, self._busy_seq, hs.ERR_STOPPED)
            self._busy_seq = None
        self._last_seq = self._int("cmd_seq")  # cancel a command written but not yet taken
        self._put("stop_ack", [value])

    def _finish(self, state: SimState) -> None:
        if self.never_finish:
            return
        seq, self._busy_seq = self._busy_seq, None
        if float(np.max(np.abs(state.q - self._target))) > TARGET_TOLERANCE_RAD:
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_NOT_AT_TARGET)
        else:
            self.answer(hs.STATUS_DONE, seq)

    def _take(self, seq: int, state: SimState) -> None:
        if self._busy_seq is not None:
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_BUSY)
            return
        kind = self._int("cmd_kind") if "cmd_kind" in self.map else hs.KIND_MOVE
        if kind == hs.KIND_PAYLOAD and "payload_mass" in self.map:
            self._set_payload(seq)
        elif kind == hs.KIND_MOVE:
            self._move(seq)
        else:
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_UNKNOWN_KIND)

    def _move(self, seq: int) -> None:
        m = self.map
        target = np.asarray(self._get("cmd_target")) * si_factor(m["cmd_target"])
        speed = self._get("cmd_speed")[0] * si_factor(m["cmd_speed"])
        accel = self._get("cmd_accel")[0] * si_factor(m["cmd_accel"])
        if not (np.all(np.isfinite(target)) and np.all(np.abs(target) <= MAX_ABS_TARGET_RAD)):
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_BAD_TARGET)
            return
        if not (0 < speed <= self._max_speed and 0 < accel <= 4 * self._max_accel):
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_BAD_SPEED)
            return
        try:
            self.robot.move_joints(target, speed, accel)
        except SimRefused:
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_SAFETY)
            return
        self._move_id = self.robot.snapshot().move_id + 1  # the state of the next tick carries it
        self._target = target
        self._busy_seq = seq
        self.answer(hs.STATUS_BUSY, seq)

    def _set_payload(self, seq: int) -> None:
        m = self.map
        mass = self._get("payload_mass")[0] * si_factor(m["payload_mass"])
        cog = [c * si_factor(m["payload_cog"]) for c in self._get("payload_cog")]
        if not (0 <= mass <= 100 and all(abs(c) <= 2.0 for c in cog)):
            self.answer(hs.STATUS_ERROR, seq, hs.ERR_BAD_PAYLOAD)
            return
        self.payload_setting = (mass, (cog[0], cog[1], cog[2]))
        if "payload_readback_mass" in m:
            self._put("payload_readback_mass", [mass / si_factor(m["payload_readback_mass"])])
            self._put("payload_readback_cog", [c / si_factor(m["payload_readback_cog"]) for c in cog])
        self.answer(hs.STATUS_DONE, seq)
