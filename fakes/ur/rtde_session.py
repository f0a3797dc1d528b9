"""One client of the simulated controller's RTDE server (port 30004).

Handles the setup packages (protocol version, controller version, output and input recipes,
start, pause), writes input data packages into the controller's registers, and sends the
output recipes' data packages at their frequency *in simulated time* from a sender thread.

The stream faults (``stall_stream``, ``garbage``) act on *sample stream* sessions only: those
whose output recipe carries none of the control script's ``output_int_register_*`` (that is,
ur_rtde's receive interface, not its control interface), so that the command channel keeps
working, as the simulated-controller contract says of these faults.
"""

from __future__ import annotations

import collections
import math
import os
import socket
import struct
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from payload_agent.fakes import ur_rtde_protocol as rp
from payload_agent.fakes.tcp_server import shutdown_socket
from payload_agent.fakes.ur.outputs import GETTERS, Snapshot

if TYPE_CHECKING:
    from payload_agent.fakes.ur.controller import URControllerCore

CLIENT_STALL_S = 0.5  # a client whose socket takes nothing for this long is dropped
BACKLOG_WAIT_S = 1.0  # wall time the simulation waits for the fake's own sender before packages are lost


@dataclass
class OutputRecipe:
    rid: int
    names: list[str]
    types: list[str]
    struct: struct.Struct
    period: float
    valid: bool
    next_t: float | None = None


@dataclass
class InputRecipe:
    rid: int
    names: list[str]
    types: list[str]
    struct: struct.Struct


class RTDESession:
    """One client on port 30004."""

    def __init__(self, ctrl: "URControllerCore", conn: socket.socket):
        self.ctrl = ctrl
        self.conn = conn
        self.protocol = 1
        self.outputs: list[OutputRecipe] = []
        self.inputs: dict[int, InputRecipe] = {}
        self.started = False
        self.alive = True
        self.send_lock = threading.Lock()
        self.cv = threading.Condition()
        self.queue: collections.deque = collections.deque()
        self.max_queue = 1000
        self.overflowed = False
        self.blocked_since: float | None = None  # the sender waits in sendall: the client does not read
        self.dropped_packages = 0
        self.sent_packages = 0
        self.errors: list[str] = []
        self.sender = threading.Thread(target=self._send_loop, daemon=True, name="ur-fake-rtde-send")
        self.sender.start()

    @property
    def is_sample_stream(self) -> bool:
        """A session that only streams robot state (no control script registers in its outputs)."""
        return not any(n.startswith("output_int_register_") for rec in self.outputs for n in rec.names)

    def _stream_fault(self) -> str | None:
        fault = self.ctrl.faults.stream_fault
        return fault if fault is not None and self.is_sample_stream else None

    # -- reader ---------------------------------------------------------------------------------
    def serve(self) -> None:
        while self.alive:
            try:
                size, kind, payload = rp.recv_package(self.conn)
            except ValueError as exc:  # cannot re-synchronize: hang up
                self._error(f"bad framing: {exc}; closing the connection")
                return
            self._handle(kind, payload)

    def _reply(self, kind: int, payload: bytes) -> None:
        with self.send_lock:
            self.conn.sendall(rp.pack(kind, payload))

    def _error(self, text: str, notify: bool = False) -> None:
        self.errors.append(text)
        self.ctrl.rtde_errors.append(text)
        self.ctrl.note(f"rtde: {text}")
        if notify:
            with self.send_lock:
                try:
                    self.conn.sendall(rp.text_message(text, "RTDE", rp.MSG_ERROR))
                except OSError:
                    pass

    def _handle(self, kind: int, payload: bytes) -> None:
        c = self.ctrl
        if kind == rp.REQUEST_PROTOCOL_VERSION:
            ok = len(payload) == 2 and struct.unpack(">H", payload)[0] in (1, 2)
            if ok:
                self.protocol = struct.unpack(">H", payload)[0]
            else:
                self._error(f"protocol version request refused (payload {payload.hex()})")
            self._reply(kind, bytes([1 if ok else 0]))
        elif kind == rp.GET_URCONTROL_VERSION:
            if payload:
                self._error("controller version request with a payload", notify=True)
                return
            self._reply(kind, struct.pack(">IIII", *c.controller_version))
        elif kind == rp.CONTROL_PACKAGE_SETUP_OUTPUTS:
            self._setup_outputs(payload)
        elif kind == rp.CONTROL_PACKAGE_SETUP_INPUTS:
            self._setup_inputs(payload)
        elif kind == rp.CONTROL_PACKAGE_START:
            ok = not payload and any(r.valid for r in self.outputs)
            if ok:
                with self.cv:
                    for r in self.outputs:
                        r.next_t = None
                    self.started = True
            else:
                self._error("start refused: no valid output recipe" if not payload else "start with a payload")
            self._reply(kind, bytes([1 if ok else 0]))
        elif kind == rp.CONTROL_PACKAGE_PAUSE:
            with self.cv:
                self.started = False
                self.queue.clear()
            self._reply(kind, bytes([1]))
        elif kind == rp.DATA_PACKAGE:
            self._input_data(payload)
        else:
            self._error(f"unknown package type {kind}", notify=True)

    @staticmethod
    def _split_names(text: bytes) -> list[str]:
        names = text.decode(errors="replace").split(",")
        if names and names[-1] == "":
            names.pop()  # ur_rtde appends a comma after every name
        return names

    def _setup_outputs(self, payload: bytes) -> None:
        c = self.ctrl
        if self.started:
            self._error("output setup while synchronizing", notify=True)
            return
        if self.protocol >= 2:
            if len(payload) < 8:
                self._reply(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, bytes([0]))
                return
            freq = struct.unpack(">d", payload[:8])[0]
            names = self._split_names(payload[8:])
        else:
            freq = c.max_frequency_hz
            names = self._split_names(payload)
        types = [rp.OUTPUT_TYPES[n] if rp.output_available(n, c.controller_version) else "NOT_FOUND" for n in names]
        freq_ok = math.isfinite(freq) and 0 < freq <= c.max_frequency_hz
        valid = bool(names) and "NOT_FOUND" not in types and freq_ok
        rid = len(self.outputs) + 1 if valid else 0
        if rid > 255:  # the recipe id is one byte: no more recipes on this connection
            valid, rid = False, 0
        if valid:
            rec = OutputRecipe(rid, names, types, rp.recipe_struct(types), 1.0 / freq, True)
            with self.cv:
                self.outputs.append(rec)
        else:
            self._error(f"output recipe refused: frequency {freq} Hz, names {names}, types {types}")
        c.note(f"rtde: output setup {freq:g} Hz id {rid}: {','.join(names)}")
        self._reply(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, bytes([rid]) + ",".join(types).encode())

    def _setup_inputs(self, payload: bytes) -> None:
        c = self.ctrl
        if self.started:
            self._error("input setup while synchronizing", notify=True)
            return
        names = self._split_names(payload)
        types = []
        with c.lock:
            for n in names:
                t = rp.INPUT_TYPES.get(n)
                owner = c.input_owner.get(n)
                if t is None:
                    types.append("NOT_FOUND")
                elif owner is not None and owner is not self:
                    types.append("IN_USE")
                else:
                    types.append(t)
            valid = bool(names) and not any(t in ("NOT_FOUND", "IN_USE") for t in types)
            rid = len(self.inputs) + 1 if valid else 0
            if rid > 255:
                valid, rid = False, 0
            if valid:
                for n in names:
                    c.input_owner[n] = self
                self.inputs[rid] = InputRecipe(rid, names, types, rp.recipe_struct(types))
            else:
                self._error(f"input recipe refused: {names} -> {types}")
        c.note(f"rtde: input setup id {rid}: {','.join(names)}")
        self._reply(rp.CONTROL_PACKAGE_SETUP_INPUTS, bytes([rid]) + ",".join(types).encode())

    def _input_data(self, payload: bytes) -> None:
        if not payload:
            self._error("data package without a recipe id", notify=True)
            return
        rec = self.inputs.get(payload[0])
        if rec is None:
            self._error(f"data package for unknown input recipe {payload[0]}", notify=True)
            return
        if len(payload) != rec.struct.size:
            self._error(f"data package for input recipe {rec.rid} has {len(payload)} bytes, "
                        f"expected {rec.struct.size}", notify=True)
            return
        values = rp.unflatten(rec.types, rec.struct.unpack(payload)[1:])
        c = self.ctrl
        with c.lock:
            for name, val in zip(rec.names, values):
                if name.startswith("input_int_register_"):
                    c.in_int[int(name[19:])] = val
                elif name.startswith("input_double_register_"):
                    c.in_dbl[int(name[22:])] = val
                elif name.startswith("input_bit_register_"):
                    bit = int(name[19:])
                    c.in_bits = (c.in_bits | (1 << bit)) if val else (c.in_bits & ~(1 << bit))
                elif name == "input_bit_registers0_to_31":
                    c.in_bits = (c.in_bits & ~0xFFFFFFFF) | val
                elif name == "input_bit_registers32_to_63":
                    c.in_bits = (c.in_bits & ~(0xFFFFFFFF << 32)) | (val << 32)
                else:
                    c.inputs_misc[name] = val

    # -- writer ---------------------------------------------------------------------------------
    def on_tick(self, s: Snapshot) -> None:
        if not self.started or not self.alive:
            return
        stalled = self._stream_fault() == "stall_stream"
        with self.cv:
            for rec in self.outputs:
                if rec.next_t is None:  # packages are due on the exact clock; they carry the reported time
                    rec.next_t = s.t_exact
                if s.t_exact + 1e-9 >= rec.next_t:
                    if not stalled:
                        self.queue.append((rec, s))
                    rec.next_t += rec.period
                    if rec.next_t < s.t_exact:  # fell behind (paused clock): do not burst
                        rec.next_t = s.t_exact + rec.period
            deadline = time.monotonic() + BACKLOG_WAIT_S
            while len(self.queue) > self.max_queue and self.alive and time.monotonic() < deadline:
                self.cv.notify()
                self.cv.wait(0.05)  # the fake's own sender is behind (a busy machine): simulated time waits
            if len(self.queue) > self.max_queue:
                blocked = self.blocked_since
                if blocked is not None and time.monotonic() - blocked > CLIENT_STALL_S:
                    self.overflowed = True  # the real controller drops a client that does not read
                    self.alive = False
                else:  # the fake's own sender fell behind (a busy machine): the oldest packages are lost
                    while len(self.queue) > self.max_queue:
                        self.queue.popleft()
                        self.dropped_packages += 1
            self.cv.notify()
        if self.overflowed:
            self.ctrl.note("rtde: client does not read; closing its connection")
            shutdown_socket(self.conn)

    def _pack(self, rec: OutputRecipe, s: Snapshot) -> bytes | None:
        try:
            payload = rec.struct.pack(rec.rid, *rp.flatten(rec.types, [GETTERS[n](s) for n in rec.names]))
        except Exception as exc:  # a bug in a getter: make it visible
            self._error(f"cannot pack data package: {exc!r}")
            return None
        if self._stream_fault() == "garbage":
            mode = self.ctrl.faults.params("garbage").get("mode", "payload")
            if mode == "framing":  # bytes that are not RTDE at all
                return os.urandom(len(payload) + rp.HEADER_SIZE)
            payload = payload[:1] + os.urandom(len(payload) - 1)  # well framed, content corrupted
        return rp.pack(rp.DATA_PACKAGE, payload)

    def _send(self, data: bytes) -> None:
        with self.send_lock:
            self.blocked_since = time.monotonic()
            try:
                self.conn.sendall(data)
            finally:
                self.blocked_since = None

    def _send_loop(self) -> None:
        # The real controller sends one package every cycle. The simulated clock may fall
        # behind and then run a few cycles back to back (a loaded machine); packages sent
        # in such a burst would arrive together, and clients that keep only the newest
        # package (ur_rtde does) would lose the others. So packages are spaced by at
        # least 60 % of their period in wall time, unless a backlog has built up.
        last_send = 0.0
        while True:
            with self.cv:
                while self.alive and not self.queue:
                    self.cv.wait(0.5)
                if not self.alive:
                    return
                items = list(self.queue)
                self.queue.clear()
                self.cv.notify_all()  # a simulation thread waiting for room goes on
            scale = max(self.ctrl.robot.time_scale, 1e-9)
            min_gap = 0.6 * min(rec.period for rec, _ in items) / scale
            pace = min_gap >= 0.0001 and len(items) <= 25
            chunks = [c for c in (self._pack(rec, s) for rec, s in items) if c is not None]
            if not chunks:
                continue
            try:
                if pace:
                    for chunk in chunks:
                        wait = last_send + min_gap - time.monotonic()
                        if wait > 0:
                            time.sleep(wait)
                        self._send(chunk)
                        last_send = time.monotonic()
                else:
                    self._send(b"".join(chunks))
                    last_send = time.monotonic()
                self.sent_packages += len(chunks)
            except OSError:
                self.alive = False
                return

    def close(self) -> None:
        with self.cv:
            self.alive = False
            self.started = False
            self.cv.notify_all()
        shutdown_socket(self.conn)
