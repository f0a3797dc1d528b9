"""The motion handshake between payload-agent and a program on the robot, over Modbus registers.

The protocol (documented for other controllers in docs/modbus.md; the UR program is
procedures/ur_modbus_handshake.script):

1. The agent writes the command's fields first: target joint angles, leading-joint speed and
   acceleration, the command kind (1 move, 2 set payload) and, for kind 2, the payload.
2. It then writes a new sequence number to ``cmd_seq``, last and in a request of its own. A
   number different from the last one the program took starts the command (never 0).
3. The program answers in ``status`` (0 idle, 1 busy, 2 done, 3 error) with ``error_code``,
   and echoes the command's number in ``ack_seq``. It writes ``error_code`` and ``status``
   before ``ack_seq``, so that an ``ack_seq`` equal to the command's number always comes with
   that command's status.
4. A new value in ``stop_request`` makes the program stop the arm at once, cancel any command
   not yet taken, and then echo the value in ``stop_ack``. The program polls it every cycle,
   also while a move runs. It is the motion supervision's stop path for this driver.
5. ``heartbeat`` (optional but recommended) changes every program cycle, so the agent can tell
   a running program from a stopped one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

from payload_agent.drivers.modbus.bus import ModbusBus, ModbusTimeout
from payload_agent.drivers.modbus.registers import Entry, group_reads, int_range
from payload_agent.drivers.modbus.regmap import RegisterMap

STATUS_IDLE, STATUS_BUSY, STATUS_DONE, STATUS_ERROR = 0, 1, 2, 3
STATUS_NAMES = {STATUS_IDLE: "idle", STATUS_BUSY: "busy", STATUS_DONE: "done", STATUS_ERROR: "error"}
KIND_MOVE, KIND_PAYLOAD = 1, 2

ERR_BAD_TARGET = 1
ERR_UNKNOWN_KIND = 2
ERR_BUSY = 3
ERR_STOPPED = 4
ERR_NOT_AT_TARGET = 5
ERR_BAD_SPEED = 6
ERR_SAFETY = 7
ERR_BAD_PAYLOAD = 8
ERROR_NAMES = {
    ERR_BAD_TARGET: "target out of the joint range",
    ERR_UNKNOWN_KIND: "unknown command kind",
    ERR_BUSY: "a command arrived while a move was running",
    ERR_STOPPED: "stopped by a stop request",
    ERR_NOT_AT_TARGET: "the arm did not reach the target",
    ERR_BAD_SPEED: "speed or acceleration not positive or too high",
    ERR_SAFETY: "a safety stop ended the move",
    ERR_BAD_PAYLOAD: "payload out of range",
}
ANSWER_SIGNALS = ("status", "ack_seq", "error_code", "stop_ack", "heartbeat")


def error_text(code: int) -> str:
    return f"error {code} ({ERROR_NAMES.get(code, 'unknown error code')})"


@dataclass(frozen=True)
class Answer:
    status: int
    ack_seq: int
    error_code: int
    stop_ack: int
    heartbeat: int | None
    t: float  # monotonic receive time

    def describe(self) -> str:
        return (f"status {STATUS_NAMES.get(self.status, self.status)}, ack_seq {self.ack_seq}, "
                f"error_code {self.error_code}")


def next_counter(entry: Entry, current: int) -> int:
    """The next sequence/stop number after ``current``: wraps within the type, never 0."""
    lo, hi = int_range(entry.type)
    top = hi if hi > 0 else 1
    nxt = int(current) + 1
    return 1 if nxt > top or nxt <= 0 else nxt


class Handshake:
    """The agent's side of the protocol for one register map."""

    def __init__(self, regmap: RegisterMap, bridge_gaps: int):
        self.map = regmap
        self._answers = [regmap[n] for n in ANSWER_SIGNALS if n in regmap]
        self._answer_blocks = group_reads(self._answers, bridge_gaps)
        self._last_stop: int | None = None  # the stop_request value last read or written

    def _read_int(self, bus: ModbusBus, name: str) -> int:
        entry = self.map[name]
        block = group_reads([entry])[0]
        return int(entry.raw_values(bus.read(block))[0])

    def read_answer(self, bus: ModbusBus) -> Answer:
        raw: dict[str, int] = {}
        for block in self._answer_blocks:
            words = bus.read(block)
            for e in block.entries:
                raw[e.name] = int(e.raw_values(block.slice_for(e, words))[0])
        return Answer(raw["status"], raw["ack_seq"], raw["error_code"], raw["stop_ack"], raw.get("heartbeat"),
                      time.monotonic())

    def send(self, bus: ModbusBus, fields: Sequence[tuple[Entry, Sequence[float]]]) -> int:
        """Write the fields, then a new sequence number (last, alone); returns that number.

        Encoding errors (a value that does not fit its register) raise before anything is written.
        """
        for entry, values in fields:
            entry.encode(values)  # raises EncodingError naming the entry
        seq_entry = self.map["cmd_seq"]
        seq = next_counter(seq_entry, self._read_int(bus, "cmd_seq"))
        bus.write(list(fields))
        try:
            bus.write([(seq_entry, [seq])])
        except ModbusTimeout:
            pass  # it may have arrived: the answers will tell (the caller waits for this number)
        return seq

    def learn_stop(self, bus: ModbusBus) -> None:
        """Read the current stop_request once (at connect), so that a stop needs no read first."""
        self._last_stop = self._read_int(bus, "stop_request")

    def request_stop(self, bus: ModbusBus, wait_s: float | None = None) -> int:
        """Write a new value to stop_request at once; returns it (to compare with stop_ack).

        The value follows the one read at connect (``learn_stop``), so the stop goes out in one request
        even when the device has stopped answering; a write whose reply is lost may well have arrived
        (the caller learns from stop_ack). Only a connection that cannot send raises.
        """
        entry = self.map["stop_request"]
        if self._last_stop is None:
            try:
                self._last_stop = self._read_int(bus, "stop_request")
            except ModbusTimeout:
                self._last_stop = 0
        value = next_counter(entry, self._last_stop)
        self._last_stop = value
        try:
            bus.write([(entry, [value])], wait_s=wait_s)
        except ModbusTimeout as exc:
            if "could not go out" in str(exc):
                raise  # nothing was sent: let the caller try another way
        return value

    def wait_stop_ack(self, bus: ModbusBus, value: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                if self._read_int(bus, "stop_ack") == value:
                    return True
            except ModbusTimeout:
                pass
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.005)
