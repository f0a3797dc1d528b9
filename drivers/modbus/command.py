"""Watching one handshake command (a move, a payload write) until the robot program reports it done.

Each ``poll()`` reads the program's answer once and says RUNNING, DONE or aborted(reason): the
program ended the command with an error, the safety state forbids motion, its heartbeat stopped,
or it never took the command (``ack_timeout_s``). One lost reply is not a lost connection: only a
silence longer than ``heartbeat_timeout_s`` raises (the supervision judges a move's silence sooner).
"""

from __future__ import annotations

import time
from typing import Callable

from payload_agent.drivers.modbus import handshake as hs
from payload_agent.drivers.modbus.bus import ModbusBus, ModbusTimeout
from payload_agent.drivers.modbus.options import ModbusOptions
from payload_agent.drivers.modbus.regmap import RegisterMap
from payload_agent.drivers.move_status import DONE, RUNNING, MoveStatus, aborted
from payload_agent.errors import MotionAbortedError


class CommandWatch:
    """The state of one command while the program works on it."""

    def __init__(self, seq: int, what: str, handshake: hs.Handshake, bus: ModbusBus, options: ModbusOptions,
                 regmap: RegisterMap, safety_fault: Callable[[], str | None],
                 on_reply: Callable[[], None] = lambda: None,
                 program_stopped: Callable[[float], None] = lambda timeout_s: None):
        self.seq, self.what = seq, what
        self._hs, self._bus, self._o, self._map = handshake, bus, options, regmap
        self._safety_fault, self._on_reply, self._program_stopped = safety_fault, on_reply, program_stopped
        self.t0 = self._last_answer = self._beat_t = time.monotonic()
        self._taken = False
        self._beat: int | None = None

    def poll(self) -> MoveStatus:
        """One look at the program's answer (and the safety state while it has not finished)."""
        what, seq, o = self.what, self.seq, self._o
        try:
            ans = self._hs.read_answer(self._bus)
        except ModbusTimeout:
            if time.monotonic() - self._last_answer > o.heartbeat_timeout_s:
                raise
            return RUNNING
        self._on_reply()
        now = self._last_answer = ans.t
        if ans.heartbeat is not None and ans.heartbeat != self._beat:
            self._beat, self._beat_t = ans.heartbeat, now
        if ans.ack_seq == seq:
            if ans.status == hs.STATUS_DONE:
                return DONE
            if ans.status == hs.STATUS_ERROR:
                if ans.error_code == hs.ERR_STOPPED:  # the supervision may be stopping the arm: its trip, not ours
                    self._program_stopped(o.stop_ack_wait_s + 0.5)
                return aborted(f"the robot program ended {what} {seq} with {hs.error_text(ans.error_code)}")
            self._taken = self._taken or ans.status == hs.STATUS_BUSY
        try:
            fault = self._safety_fault()
        except ModbusTimeout:
            fault = None
        if fault:
            return aborted(f"{what} {seq} aborted: {fault}")
        if "heartbeat" in self._map and now - self._beat_t > o.heartbeat_timeout_s:
            return aborted(f"the robot program stopped during {what} {seq}: its heartbeat (register "
                           f"{self._map['heartbeat'].address}) has not changed for {now - self._beat_t:.1f} s; "
                           "check the pendant")
        if not self._taken and now - self.t0 > o.ack_timeout_s:
            return aborted(f"the robot program did not take {what} {seq} within {o.ack_timeout_s:g} s "
                           f"({ans.describe()}): is payload-agent's handshake program running on the controller?")
        return RUNNING

    def wait(self, timeout_s: float, poll_s: float) -> None:
        """Poll until done (a command that moves nothing); MotionAbortedError on any other end."""
        while True:
            status = self.poll()
            if status.done:
                return
            if not status.running:
                raise MotionAbortedError(status.describe())
            if time.monotonic() - self.t0 > timeout_s:
                raise MotionAbortedError(f"{self.what} {self.seq} did not finish within {timeout_s:.1f} s")
            time.sleep(poll_s)
