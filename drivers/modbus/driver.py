"""Modbus TCP and RTU driver: register maps as data, motion through a program on the robot.

The base class (``payload_agent.drivers.base``) runs the sample stream and the motion
supervision; this module fills the hooks:

* ``_read_sample``: one block read per sample where the map allows (``registers.group_reads``),
  timestamped on receipt, paced at ``sample_rate_hz``; a reply that took far longer than the usual
  round trip is dropped (its values' time is unknown), unless the stream would then come close to
  the watchdog's gap limit. A block identical to the previous one is
  not a new sample (the device has not refreshed it yet, or it stalled); the watchdog then sees
  the gap. Decoded angles beyond ``max_abs_angle_deg`` and non-finite values are garbage: the
  stream fails and names the register.
* ``_start_move``: the handshake of ``handshake.py`` (fields first, sequence number last);
  ``_move_status`` (``command.CommandWatch``): busy, then done or error; heartbeat and safety state
  watched while waiting.
* ``_stop_command`` writes ``stop_request`` over the command connection and waits for
  ``stop_ack``; ``_stop_fresh`` does the same over a new connection (for RTU, the serial port
  reopened).

Over TCP the sample stream and the commands use two connections (a Modbus server serves
several clients); over RTU they share the one serial line.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time

import numpy as np

from payload_agent.drivers.base import (ControllerInfo, ControllerState, Driver, FlangePose, MotionLimits,
                                        MoveStatus, PayloadSetting, Sample, refused)
from payload_agent.drivers.modbus import handshake as hs
from payload_agent.drivers.modbus.bus import ModbusBus, ModbusTimeout
from payload_agent.drivers.modbus.command import CommandWatch
from payload_agent.drivers.modbus.options import ModbusOptions, endpoint, resolve_map
from payload_agent.drivers.modbus.pose import flange_from_tcp
from payload_agent.drivers.modbus.registers import EncodingError, Entry, group_reads, int_range
from payload_agent.drivers.modbus.regmap import si_factor
from payload_agent.errors import (CommunicationError, ConfigError, MotionAbortedError, RobotNotReadyError,
                                  UnsupportedCapability)

STATUS_SIGNALS = ("robot_mode", "power_on", "protective_stop", "emergency_stop", "fault_code")


STATUS_FLAGS = ("power_on", "protective_stop", "emergency_stop")  # registers that hold 0 or 1

class ModbusDriver(Driver):
    name = "modbus"
    options_class = ModbusOptions
    simulator = "payload_agent.fakes.modbus.controller:SimulatedModbusRobot"
    default_target_tolerance_deg = 0.3  # the programs' own "arrived" check is 0.005 rad (docs/modbus.md)

    def __init__(self, options: ModbusOptions, limits: MotionLimits, supervision=None):
        super().__init__(options, limits, supervision)
        self.map = resolve_map(options)
        if limits.n_joints != 6:
            raise ConfigError("robot", f"the modbus driver's maps carry 6 joints, the robot has {limits.n_joints}")
        self.effort_unit = self.map.effort_unit
        update = self.map.update_hz
        self.poll_period_s = 1.0 / options.sample_rate_hz
        self.nominal_period_s = max(self.poll_period_s, 1.0 / update if update else 0.0)
        rtu = options.transport == "rtu"
        self.command_poll_s = self.move_poll_s = options.command_poll_s or (0.05 if rtu else 0.01)
        self.reports_flange_pose = self.map.has_all("tcp_position", "tcp_rotation")
        self.endpoint = endpoint(options)
        gaps = self.map.bridge_gaps
        names = [n for n in ("joint_angles", "joint_revolutions", "joint_efforts", "timestamp") if n in self.map]
        self._sample_blocks = group_reads([self.map[n] for n in names], gaps)
        self._status_blocks = group_reads([self.map[n] for n in STATUS_SIGNALS if n in self.map], gaps)
        if rtu:  # a sample cannot come faster than the line carries it (request + reply, 10 bits a byte)
            line_bytes = sum(8 + 5 + (b.count if b.table in ("coil", "discrete_input") else 2 * b.count)
                             for b in self._sample_blocks)
            self.nominal_period_s = max(self.nominal_period_s, 1.5 * line_bytes * 10.0 / options.baudrate)
        self.handshake = hs.Handshake(self.map, gaps)
        self._stream: ModbusBus | None = None
        self._cmd: ModbusBus | None = None
        self._next_poll = 0.0
        self._last_raw: tuple | None = None
        self._t_wrap = 0.0
        self._round_trips: collections.deque[float] = collections.deque(maxlen=64)
        self._last_reply_t = 0.0
        self._fields: list[tuple[Entry, list[float]]] = []
        self._watch: CommandWatch | None = None
        self._t_last: float | None = None
        self._max_angle = math.radians(options.max_abs_angle_deg)

    def describe_endpoint(self) -> str:
        return self.endpoint.describe()

    # -- connection ---------------------------------------------------------------------------
    def _open(self) -> None:
        self._cmd = ModbusBus(self.endpoint, "command connection")
        self._cmd.open()
        if self.endpoint.transport == "tcp":  # sample reads time out well within the watchdog's gap limit
            stream_timeout = min(self.endpoint.timeout_s, max(0.01, 0.4 * self.gap_limit_s))
            self._stream = ModbusBus(dataclasses.replace(self.endpoint, timeout_s=stream_timeout), "sample connection")
            try:
                self._stream.open()
            except CommunicationError:
                self._cmd.close()
                raise
        else:  # one serial line for both
            self._stream = self._cmd
        try:
            self.handshake.learn_stop(self._cmd)
        except CommunicationError:
            self._close()
            raise
        self._last_raw = None
        self._next_poll = time.monotonic()

    def _close(self) -> None:
        for bus in (self._stream, self._cmd):
            if bus is not None:
                bus.close()

    def _command_alive(self) -> bool:
        return self._cmd is not None and self._cmd.alive

    # -- sample stream ------------------------------------------------------------------------
    def _read_sample(self, timeout_s: float) -> Sample | None:
        now = time.monotonic()
        if now < self._next_poll:
            time.sleep(min(timeout_s, self._next_poll - now))
            if time.monotonic() < self._next_poll:
                return None
        self._next_poll = max(self._next_poll + self.poll_period_s, time.monotonic())
        t_send = time.monotonic()
        try:
            words = [self._stream.read(b) for b in self._sample_blocks]
        except ModbusTimeout as exc:  # a late reply is a gap; during a move, a long silence is named
            silent = time.monotonic() - self._last_reply_t
            if self.supervising and silent > 0.8 * self.gap_limit_s:
                raise CommunicationError(f"the controller stopped answering: {exc} (no reply for "
                                         f"{1000 * silent:.0f} ms)") from None
            return None
        t_recv = self._last_reply_t = time.monotonic()
        raw = tuple(tuple(w) for w in words)
        if self.options.repeat_is_stale and raw == self._last_raw:
            return None
        self._last_raw = raw
        latest = self.latest_sample
        if self._reply_too_slow(t_recv - t_send) and latest is not None \
                and t_recv - latest.t_recv < 0.5 * self.gap_limit_s:
            return None  # when within the round trip the device took these values is unknown: not a sample
        values = self._decode(self._sample_blocks, words)
        q = np.asarray(values["joint_angles"]) * si_factor(self.map["joint_angles"])
        if "joint_revolutions" in values:
            q = q + np.asarray(values["joint_revolutions"]) * si_factor(self.map["joint_revolutions"])
        for j, v in enumerate(q):
            if not (math.isfinite(v) and abs(v) <= self._max_angle):
                raise CommunicationError(self._garbage_text("joint_angles", j, v, "rad"))
        effort = values["joint_efforts"]
        for j, v in enumerate(effort):
            if not math.isfinite(v):
                raise CommunicationError(self._garbage_text("joint_efforts", j, v, self.effort_unit))
        t_ctrl = self._controller_time(values["timestamp"][0]) if "timestamp" in values else None
        if t_ctrl is not None and not math.isfinite(t_ctrl):
            raise CommunicationError(self._garbage_text("timestamp", 0, t_ctrl, "s"))
        return Sample(t_ctrl, t_recv, tuple(float(v) for v in q), tuple(float(v) for v in effort))

    def _reply_too_slow(self, round_trip_s: float) -> bool:
        """A reply far slower than usual (a loaded host, a congested link) cannot be timed on receipt."""
        trips = self._round_trips
        trips.append(round_trip_s)
        if len(trips) < 16:
            return False
        limit = self.options.max_round_trip_s or max(0.005, 3.0 * float(np.median(trips)) + 0.002)
        return round_trip_s > limit

    def _garbage_text(self, name: str, j: int, value: float, unit: str) -> str:
        e = self.map[name]
        regs = f"register {e.register_of(j)}" + (f" (and revolution counter {self.map['joint_revolutions'].register_of(j)})"
                                                 if name == "joint_angles" and "joint_revolutions" in self.map else "")
        return (f"{self.endpoint.describe()} sent an impossible {name}[{j}] = {value!r} {unit} in {e.table} {regs}: "
                f"the register map does not match the device, or the device sends garbage")

    def _controller_time(self, t: float) -> float:
        e = self.map["timestamp"]
        if e.is_integer and self._t_last is not None and t < self._t_last - 1.0:
            lo, hi = int_range(e.type)
            self._t_wrap += (hi - lo + 1) * e.scale
        self._t_last = t
        return t + self._t_wrap

    @staticmethod
    def _decode(blocks, words) -> dict[str, list[float]]:
        out: dict[str, list[float]] = {}
        for block, w in zip(blocks, words):
            for e in block.entries:
                out[e.name] = e.decode(block.slice_for(e, w))
        return out

    def _read(self, *names: str) -> dict[str, list[float]]:
        """Decoded values of some signals over the command connection (grouped reads)."""
        entries = [self.map[n] for n in names if n in self.map]
        blocks = group_reads(entries, self.map.bridge_gaps)
        return self._decode(blocks, [self._cmd.read(b) for b in blocks])

    # -- motion -------------------------------------------------------------------------------
    def _prepare_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> None:
        """Every field must fit its register (the safety state is watched during the move: state() would wait
        a heartbeat period)."""
        m = self.map
        self._fields = [(m["cmd_target"], list(target / si_factor(m["cmd_target"]))),
                        (m["cmd_speed"], [speed_rad_s / si_factor(m["cmd_speed"])]),
                        (m["cmd_accel"], [accel_rad_s2 / si_factor(m["cmd_accel"])])]
        if "cmd_kind" in m:
            self._fields.append((m["cmd_kind"], [hs.KIND_MOVE]))
        try:
            for entry, values in self._fields:
                entry.encode(values)
        except EncodingError as exc:
            raise MotionAbortedError(f"cannot send the move through the register map: {exc}; nothing was sent") \
                from None

    def _start_move(self, target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> MoveStatus | None:
        answer = self.handshake.read_answer(self._cmd)  # supervised: a silent program trips the watchdog
        if answer.status == hs.STATUS_BUSY:
            return refused(f"the robot program is still busy with command {answer.ack_seq}; nothing was sent")
        self._watch = self._command_watch(self.handshake.send(self._cmd, self._fields), "move")
        return None

    def _move_status(self) -> MoveStatus:
        return self._watch.poll()

    def _command_watch(self, seq: int, what: str) -> CommandWatch:
        # RTU: the stream shares the line, the stream's watchdog covers its silence
        on_reply = self.command_ok if self.endpoint.transport == "tcp" else (lambda: None)
        return CommandWatch(seq, what, self.handshake, self._cmd, self.options, self.map, self._safety_fault,
                            on_reply, self.wait_for_trip)

    def _stop_command(self) -> bool:
        # not behind a read that waits for its reply: then the base goes straight to a new connection
        wait_s = 0.02 if self.endpoint.transport == "tcp" else 0.06  # RTU: a sample read may be on the line
        value = self.handshake.request_stop(self._cmd, wait_s=wait_s)
        return self.handshake.wait_stop_ack(self._cmd, value, self.options.stop_ack_wait_s)

    def _stop_fresh(self) -> bool:
        if self.endpoint.transport == "rtu":  # one line: reopen it in place (the stream shares it)
            bus = self._cmd
            bus.close()
            bus.open()
            value = self.handshake.request_stop(bus)
            return self.handshake.wait_stop_ack(bus, value, self.options.stop_ack_wait_s)
        bus = ModbusBus(self.endpoint, "stop connection")
        try:
            bus.open()
            value = self.handshake.request_stop(bus)
            return self.handshake.wait_stop_ack(bus, value, self.options.stop_ack_wait_s)
        finally:
            bus.close()

    # -- state --------------------------------------------------------------------------------
    def _status(self) -> dict[str, int]:
        """The safety and mode registers. A flag that reads neither 0 nor 1 is a garbled or misdirected reply
        (once a late reply of another block, 1311, was taken for the emergency stop): refused, never read as set."""
        out: dict[str, int] = {}
        for block in self._status_blocks:
            words = self._cmd.read(block)
            for e in block.entries:
                out[e.name] = int(e.raw_values(block.slice_for(e, words))[0])
                if e.name in STATUS_FLAGS and out[e.name] not in (0, 1):
                    raise CommunicationError(f"the controller answered the status read with {out[e.name]} for "
                                             f"{e.name} ({e.table} {e.address}), which is neither 0 nor 1: a garbled "
                                             "or misdirected reply; the status is unknown")
        return out

    def _safety_fault(self) -> str | None:
        st = self._status()
        if st.get("emergency_stop"):
            return "the emergency stop is active: release it and reset the robot at the pendant"
        if st.get("protective_stop"):
            return "the robot is in a protective stop: find the cause, then clear it at the pendant"
        if "power_on" in st and not st["power_on"]:
            return "the arm is not powered: power it on and release the brakes at the pendant"
        if "robot_mode" in st:
            e = self.map["robot_mode"]
            if e.ok_values is not None and st["robot_mode"] not in e.ok_values:
                want = " or ".join(e.value_names.get(v, str(v)) for v in e.ok_values)
                have = e.value_names.get(st["robot_mode"], "unknown")
                return f"the robot mode is {have} ({st['robot_mode']}); motion needs {want}"
        if st.get("fault_code"):
            e = self.map["fault_code"]
            return f"the controller reports fault {st['fault_code']} ({e.value_names.get(st['fault_code'], '?')})"
        return None

    def _program_running(self) -> bool:
        if "heartbeat" not in self.map:
            return True
        first = self.handshake.read_answer(self._cmd).heartbeat
        deadline = time.monotonic() + self.options.heartbeat_timeout_s
        while time.monotonic() < deadline:
            time.sleep(0.01)
            if self.handshake.read_answer(self._cmd).heartbeat != first:
                return True
        return False

    def state(self) -> ControllerState:
        st = self._status()
        ans = self.handshake.read_answer(self._cmd)
        detail = ", ".join(f"{k}={v}" for k, v in st.items()) + f", program {ans.describe()}"
        fault = self._safety_fault()
        estop, prot = bool(st.get("emergency_stop")), bool(st.get("protective_stop"))
        moving = ans.status == hs.STATUS_BUSY
        if fault:
            return ControllerState(False, fault, estop, prot, moving, detail)
        if not self._program_running():
            return ControllerState(False, f"payload-agent's handshake program is not running: its heartbeat "
                                          f"(register {self.map['heartbeat'].address}) did not change for "
                                          f"{self.options.heartbeat_timeout_s:g} s. Start it on the controller "
                                          f"(see docs/modbus.md)", estop, prot, moving, detail)
        return ControllerState(True, "", estop, prot, moving, detail)

    def identify(self) -> ControllerInfo:
        fw = ""
        if self.map.has_all("firmware_major", "firmware_minor"):
            v = self._read("firmware_major", "firmware_minor")
            fw = f"{int(v['firmware_major'][0])}.{int(v['firmware_minor'][0])}"
        # a register map carries no serial number: driver.serial declares it (never the address: it changes)
        return ControllerInfo(self.map.vendor or "Modbus device", self.map.model or (self.map.preset or "custom map"),
                              fw, "")

    # -- pose, payload, inputs ----------------------------------------------------------------
    def flange_pose(self) -> FlangePose | None:
        if not self.reports_flange_pose:
            return None
        names = ("tcp_position", "tcp_rotation", "tcp_offset_position", "tcp_offset_rotation")
        v = self._read(*names)
        si = {n: np.asarray(v[n]) * si_factor(self.map[n]) for n in v}
        for n, arr in si.items():  # float32 registers can hold NaN and infinities
            if not np.all(np.isfinite(arr)):
                j = int(np.argmin(np.isfinite(arr)))
                raise CommunicationError(self._garbage_text(n, j, float(arr[j]), "m" if "position" in n else "rad"))
        p, R = flange_from_tcp(si["tcp_position"], si["tcp_rotation"], si.get("tcp_offset_position"),
                               si.get("tcp_offset_rotation"))
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
            raise CommunicationError(f"{self.endpoint.describe()} sent a TCP pose too large to be real: "
                                     f"{ {n: a.tolist() for n, a in si.items()} }")
        return FlangePose(tuple(float(x) for x in p), tuple(tuple(float(x) for x in row) for row in R))

    def capabilities(self) -> frozenset[str]:
        needs = {"read_payload": ("payload_readback_mass", "payload_readback_cog"),
                 "write_payload": ("payload_mass", "payload_cog", "cmd_kind"),
                 "read_digital_input": ("digital_inputs",), "read_trigger": ("tool_change",)}
        return frozenset(c for c in super().capabilities() if self.map.has_all(*needs[c]))

    def read_payload(self) -> PayloadSetting:
        if not self.map.has_all("payload_readback_mass", "payload_readback_cog"):
            raise UnsupportedCapability("the register map has no payload_readback_mass/_cog: the payload cannot "
                                        "be read back")
        v = self._read("payload_readback_mass", "payload_readback_cog")
        cog = np.asarray(v["payload_readback_cog"]) * si_factor(self.map["payload_readback_cog"])
        mass = v["payload_readback_mass"][0] * si_factor(self.map["payload_readback_mass"])
        if not (math.isfinite(mass) and np.all(np.isfinite(cog))):  # a NaN would pass any readback comparison
            raise CommunicationError(f"{self.endpoint.describe()} reads back a payload of {mass} kg at "
                                     f"{cog.tolist()} m (payload_readback_mass/_cog): not finite numbers")
        return PayloadSetting(mass, tuple(float(c) for c in cog))

    def write_payload(self, payload: PayloadSetting) -> None:
        m = self.map
        if not m.has_all("payload_mass", "payload_cog", "cmd_kind"):
            raise UnsupportedCapability("the register map has no payload_mass/payload_cog: the payload cannot be "
                                        "written through it")
        fields = [(m["payload_mass"], [payload.mass_kg / si_factor(m["payload_mass"])]),
                  (m["payload_cog"], [c / si_factor(m["payload_cog"]) for c in payload.cog_m]),
                  (m["cmd_kind"], [hs.KIND_PAYLOAD])]
        try:
            seq = self.handshake.send(self._cmd, fields)
        except EncodingError as exc:
            raise RobotNotReadyError(f"cannot write the payload through the register map: {exc}") from None
        try:
            self._command_watch(seq, "payload command").wait(5.0, self.command_poll_s)
        except MotionAbortedError as exc:
            raise RobotNotReadyError(str(exc)) from None

    def read_digital_input(self, index: int) -> bool:
        if "digital_inputs" not in self.map:
            raise UnsupportedCapability("the register map has no digital_inputs entry")
        e = self.map["digital_inputs"]
        bits = 16 * e.width
        if not 0 <= index < bits:
            raise UnsupportedCapability(f"digital input {index} is not in {e.describe()} (bits 0-{bits - 1})")
        raw = int(e.raw_values(self._cmd.read(group_reads([e])[0]))[0])
        return bool((raw >> index) & 1)

    def read_trigger(self) -> int:
        """The map's tool-change trigger register: 0, or non-zero after a tool change (its value may be
        the tool's number, as the cell's PLC writes it)."""
        if "tool_change" not in self.map:
            raise UnsupportedCapability("the register map has no tool_change entry")
        return int(self._read("tool_change")["tool_change"][0])
