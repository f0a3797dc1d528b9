"""One simulated CiA 402 servo drive: a canopen ``LocalNode`` with the power state machine, profile
position mode, its PDOs, EMCY and heartbeat.

The node's SDO server and NMT slave are the canopen library's; this class adds what a drive
does with its object dictionary (docs/sources.md, "CANopen CiA 402"):

- the power state machine driven by the controlword (0x6040), statusword (0x6041) derived from
  it; quick stop (option code 2: ramp down, then SWITCH ON DISABLED); fault reaction;
- profile position mode (0x6060 = 1 only): a rising edge of controlword bit 4 takes the target
  (0x607A) with the profile velocity/acceleration/deceleration (0x6081/0x6083/0x6084);
  set-point acknowledge (bit 12) until bit 4 falls; target reached (bit 10) when done;
- PDOs as the master configured them over SDO, strictly: a mapping changes only while its PDO
  is invalid, its count is 0 and the node is not OPERATIONAL; only mappable objects of the right
  direction fit, 64 bits at most; TPDOs go out on SYNC (types 1-240), synchronous RPDOs act at
  the next SYNC, asynchronous ones (254/255) at once; PDOs only in NMT OPERATIONAL;
- EMCY on a fault, and EMCY 0x0000 when a fault reset clears it;
- the consumer heartbeat (CiA 301 0x1016, one entry: node id << 16 | time in ms): monitoring starts
  with the first heartbeat of that node and, once that is older than the consumer time, the drive
  sends EMCY 0x8130 and reacts as its abort connection option code (CiA 402 0x6007) says: 0 nothing,
  1 fault (fault reaction: the quick stop ramp), 2 disable voltage (the brake), 3 quick stop. It
  then waits for the next heartbeat to monitor again (EMCY 0x0000 when it comes back).
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any

import canopen
from canopen.sdo import SdoAbortedError

from payload_agent.fakes.canopen.objects import PDO_INVALID, drive_dictionary

if TYPE_CHECKING:
    from payload_agent.fakes.canopen.controller import SimulatedCANopenArm

NRTSO, SOD, RTSO, SO, OE, QSA, FRA, FAULT = ("NOT READY TO SWITCH ON", "SWITCH ON DISABLED", "READY TO SWITCH ON",
                                             "SWITCHED ON", "OPERATION ENABLED", "QUICK STOP ACTIVE",
                                             "FAULT REACTION ACTIVE", "FAULT")
STATE_BITS = {NRTSO: 0x0000, SOD: 0x0050, RTSO: 0x0031, SO: 0x0033, OE: 0x0037, QSA: 0x0017, FRA: 0x001F,
              FAULT: 0x0018}  # bits 0-6 per CiA 402 (bit 4: voltage enabled), bit 5 = 0: quick stop active
REMOTE, TARGET_REACHED, SETPOINT_ACK = 0x0200, 0x0400, 0x1000
ABORT_RANGE, ABORT_NOT_MAPPABLE, ABORT_PDO_LENGTH, ABORT_STATE = 0x06090030, 0x06040041, 0x06040042, 0x08000022
ERROR_REGISTER_BITS = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08}  # current, voltage, temperature
HEARTBEAT_ERROR = 0x8130  # CiA 301 emergency code: life guard or heartbeat error
ON_ABORT = {0: "no action", 1: "fault", 2: "disable voltage", 3: "quick stop"}  # 0x6007
DYNAMIC = {0x6041, 0x6064, 0x6077, 0x6078, 0x6061, 0x603F, 0x1001}


def pdo_config(node: canopen.LocalNode, com: int, mapping: int) -> tuple[int, bool, int, list[tuple[int, int, int]]]:
    """(COB-ID, valid, transmission type, [(index, sub-index, bits)]) of one PDO, from the node's dictionary."""
    def u(index, sub, fmt="<L"):
        return struct.unpack(fmt, node.get_data(index, sub).ljust(struct.calcsize(fmt), b"\0"))[0]
    cob = u(com, 1)
    entries = [u(mapping, k) for k in range(1, u(mapping, 0, "<B") + 1)]
    return (cob & 0x7FF, not cob & PDO_INVALID, u(com, 2, "<B"),
            [(e >> 16, (e >> 8) & 0xFF, e & 0xFF) for e in entries])


class SimDrive:
    def __init__(self, arm: "SimulatedCANopenArm", joint: int, node_id: int, *, counts_per_rad: float,
                 direction: int, zero_counts: int, rated_torque_mnm: int | None, rated_current_ma: int,
                 gain_error: float, serial: int):
        self.arm, self.joint, self.node_id = arm, joint, node_id
        self.cpr, self.direction, self.zero = float(counts_per_rad), int(direction), int(zero_counts)
        self.gain_error = float(gain_error)
        od = drive_dictionary(node_id, (0x00000A5A, 0x00402001, 0x00010004, serial))
        od[0x6075].default = int(rated_current_ma)
        if rated_torque_mnm is None:
            del od[0x6076]  # a drive without the object: the master must know its rated torque
        else:
            od[0x6076].default = int(rated_torque_mnm)
        self.rated_torque_nm = (rated_torque_mnm or 1000) / 1000.0
        self.rated_current_a = rated_current_ma / 1000.0
        self.node = canopen.LocalNode(node_id, od)
        self.node.add_read_callback(self._read)
        self.node.add_write_callback(self._write)
        self.state = SOD  # transitions 0 and 1 happen on their own at power-up
        self.controlword = 0
        self.history: list[tuple[int, str]] = []  # (controlword, state after it), for tests
        self.mode = 0
        self.ack = False
        self.end_t: float | None = None  # simulated time the current set-point's profile ends
        self.stop_end_t: float | None = None
        self.error_code = 0
        self.fault_persists = False
        self.sync_rpdos: list[tuple[list, bytes]] = []
        self._tpdos: list[tuple[int, bool, int, list]] | None = None
        self._rpdos: dict[int, tuple[int, list]] = {}
        # fault switches (the controller sets them)
        self.silent = False  # off the bus: answers nothing, hears nothing
        # consumer heartbeat (0x1016): (producer node id, consumer time s); "unconfigured", "unknown" (no heartbeat
        # yet), "active", "timeout"; the bus time of the producer's newest heartbeat
        self.consumer: tuple[int, float] | None = None
        self.consumer_state = "unconfigured"
        self.producer_t: float | None = None
        self.stalled = self.garbage = self.never_finish = False

    # -- object dictionary hooks ----------------------------------------------------------------
    def _read(self, index: int, subindex: int, od) -> Any:
        if index == 0x6041:
            return self.statusword()
        if index in (0x6064, 0x6077, 0x6078):
            pos, effort = self.arm.joint_state(self.joint)
            return pos if index == 0x6064 else effort
        return {0x6061: self.mode, 0x603F: self.error_code, 0x1001: self.error_register(),
                0x6040: self.controlword}.get(index)

    def _write(self, index: int, subindex: int, od, data: bytes) -> None:
        value = od.decode_raw(data)
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, value)
            self.node.data_store.setdefault(index, {})[subindex] = bytes(data)  # (the node stores it after us)
            self._tpdos = None
            self.arm.pdo_config_changed(self)  # with the value just written: the last write validates a PDO
        elif index == 0x6060:
            if value not in (0, 1):
                raise SdoAbortedError(ABORT_RANGE)  # 0x6502: profile position only
            self.mode = value
        elif index == 0x6040:
            self.on_controlword(value)
        elif index == 0x1016 and subindex == 1:
            node, ms = value >> 16 & 0xFF, value & 0xFFFF
            self.consumer = (node, ms / 1000.0) if 0 < node < 128 and ms else None
            self.consumer_state, self.producer_t = ("unknown" if self.consumer else "unconfigured"), None
            self.arm.consumer_changed(self)
        elif index == 0x6007 and value not in ON_ABORT:
            raise SdoAbortedError(ABORT_RANGE)

    def _check_pdo_write(self, index: int, sub: int, value: int) -> None:
        base = index & 0xFE00  # 0x1400 RPDO com, 0x1600 RPDO map, 0x1800 TPDO com, 0x1A00 TPDO map
        n = index - base
        com, mapping = (0x1400 + n, 0x1600 + n) if base in (0x1400, 0x1600) else (0x1800 + n, 0x1A00 + n)
        cob, valid, _, entries = pdo_config(self.node, com, mapping)
        if base in (0x1400, 0x1800):
            if sub == 1 and valid and not value & PDO_INVALID and value & 0x7FF != cob:
                raise SdoAbortedError(ABORT_RANGE)  # a valid PDO's COB-ID cannot change
            if sub == 2 and not (value <= 240 or value >= (254 if base == 0x1400 else 252)):
                raise SdoAbortedError(ABORT_RANGE)
            return
        if valid or self.node.nmt.state == "OPERATIONAL":
            raise SdoAbortedError(ABORT_STATE)  # CiA 301: invalidate the PDO first, in PRE-OPERATIONAL
        if sub == 0:
            direction = "t" if base == 0x1A00 else "r"
            bits = 0
            for k in range(1, value + 1):
                e = struct.unpack("<L", self.node.get_data(mapping, k))[0]
                try:
                    obj = self.node.object_dictionary.get_variable(e >> 16, (e >> 8) & 0xFF)
                except KeyError:
                    obj = None
                if obj is None or not obj.pdo_mappable or direction not in obj.description or len(obj) != e & 0xFF:
                    raise SdoAbortedError(ABORT_NOT_MAPPABLE)
                bits += e & 0xFF
            if bits > 64:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
        elif entries:
            raise SdoAbortedError(ABORT_STATE)  # entries change only while the count is 0

    # -- CiA 402 --------------------------------------------------------------------------------
    def statusword(self) -> int:
        self.update()
        sw = STATE_BITS[self.state] | REMOTE
        if self.mode == 1 and self.state in (OE, QSA):
            if self.ack:
                sw |= SETPOINT_ACK
            if self.target_reached():
                sw |= TARGET_REACHED
        return sw

    def target_reached(self) -> bool:
        if self.never_finish:
            return False
        return self.end_t is None or self.arm.tick_time() >= self.end_t  # the physics tick that ended the path

    def error_register(self) -> int:
        """0x1001: generic error plus the class bit of the error code (CiA 301)."""
        code = self.error_code
        if not code:
            return 0
        if code >> 8 == 0x81:
            return 0x01 | 0x10  # communication
        if code >> 12 == 0x8:
            return 0x01 | 0x20  # device profile specific (monitoring: following error, ...)
        return 0x01 | ERROR_REGISTER_BITS.get(code >> 12, 0)

    def on_controlword(self, cw: int) -> None:
        old, self.controlword, st = self.controlword, cw, self.state
        if st in (FAULT, FRA) and cw & 0x86 == 0x02 and (not old & 0x02 or old & 0x04):
            self.arm.record_event("stop", f"node {self.node_id}: quick stop in {st}")
        if st == FAULT:
            if cw & 0x80 and not old & 0x80 and not self.fault_persists:  # fault reset, transition 15
                self.state, self.error_code = SOD, 0
                self.send_emcy(0x0000)
            self.history.append((cw, self.state))
            return
        if st in (FRA, NRTSO):
            return
        if not cw & 0x02:  # disable voltage: 7, 9, 10, 12
            if st in (RTSO, SO, OE, QSA):
                self._power_off(st)
                self.state = SOD
        elif not cw & 0x04:  # quick stop: 11 from OPERATION ENABLED, 7 / 10 otherwise
            if not old & 0x02 or old & 0x04:  # a new quick stop command (not a repeat)
                self.arm.record_event("stop", f"node {self.node_id}: quick stop in {st}")
            if st == OE:
                self.state = QSA
                self.stop_end_t = self.arm.stop_joint(self, quick=True)
                self.ack = False
            elif st in (RTSO, SO):
                self.state = SOD
        elif not cw & 0x01:  # shutdown: 2, 6, 8
            if st in (SOD, SO, OE):
                self._power_off(st)
                self.state = RTSO
        elif not cw & 0x08:  # switch on / disable operation: 3, 5
            if st == RTSO:
                self.state = SO
            elif st == OE:
                self._power_off(st)
                self.state = SO
        elif st in (RTSO, SO):  # enable operation: 4 (3 + 4 from READY TO SWITCH ON)
            self.state, self.ack, self.end_t = OE, False, None
        if cw != old or self.state != st:
            self.history.append((cw, self.state))
        if self.state == OE and self.mode == 1:
            if cw & 0x10 and not old & 0x10:
                self.arm.request_setpoint(self)
            elif not cw & 0x10:
                self.ack = False

    def _power_off(self, st: str) -> None:
        if st in (OE, QSA):
            self.arm.stop_joint(self, quick=False)  # the brake holds the joint

    def update(self) -> None:
        """Automatic transitions: quick stop finished -> SWITCH ON DISABLED (0x605A = 2)."""
        if self.state == QSA and self.stop_end_t is not None and self.arm.tick_time() >= self.stop_end_t:
            self.state, self.stop_end_t = SOD, None

    def fault(self, code: int, persists: bool = False) -> None:
        """A drive fault: fault reaction (the joint stops), FAULT, 0x603F = code, EMCY."""
        self.arm.record_event("fault", f"node {self.node_id}: 0x{code:04X} in {self.state}")
        if self.state in (OE, QSA):
            self.arm.stop_joint(self, quick=True)
        self.state, self.error_code, self.fault_persists = FAULT, code, persists
        self.ack = False
        self.send_emcy(code)

    # -- heartbeat consumer -------------------------------------------------------------------------
    def on_heartbeat_of(self, node: int, t: float) -> None:
        """A heartbeat of ``node`` went over the bus at bus time ``t`` (a drive off the bus does not hear it)."""
        if self.silent or self.consumer is None or node != self.consumer[0]:
            return
        if self.consumer_state == "timeout" and self.state != FAULT:
            self.send_emcy(0x0000)  # the producer is back: error reset
        self.consumer_state, self.producer_t = "active", t

    def check_consumer(self, now: float) -> None:
        """Consumer heartbeat monitoring at the drive's time ``now``; on a timeout, 0x6007's reaction."""
        if self.consumer_state != "active" or now - self.producer_t <= self.consumer[1]:
            return
        self.consumer_state = "timeout"
        option = struct.unpack("<h", self.node.get_data(0x6007, 0))[0]
        what = (f"node {self.node_id}: heartbeat of node {self.consumer[0]} lost ({1000 * (now - self.producer_t):.0f}"
                f" ms without it, consumer time {1000 * self.consumer[1]:.0f} ms): {ON_ABORT.get(option)} "
                f"(0x6007 = {option})")
        st = self.state
        if st in (OE, QSA) and option in (1, 2, 3):
            self.arm.record_event("stop", what)
        else:
            self.arm.record_event("heartbeat lost", what)
        if option == 1:
            self.fault(HEARTBEAT_ERROR)  # fault reaction, FAULT, EMCY
            return
        self.send_emcy(HEARTBEAT_ERROR)
        if option == 3 and st == OE:  # transition 11
            self.state, self.ack = QSA, False
            self.stop_end_t = self.arm.stop_joint(self, quick=True)
        elif option == 3 and st in (RTSO, SO) or option == 2 and st in (RTSO, SO, OE, QSA):  # 7, 9, 10, 12
            self._power_off(st)
            self.state = SOD

    def send_emcy(self, code: int) -> None:
        if not self.silent and self.node.nmt.state != "INITIALISING":
            self.node.emcy.send(code, self.error_register())

    # -- PDOs -------------------------------------------------------------------------------------
    def tpdos(self) -> list[tuple[int, bool, int, list]]:
        if self._tpdos is None:
            self._tpdos = [pdo_config(self.node, 0x1800 + n, 0x1A00 + n) for n in range(4)]
        return self._tpdos

    def rpdos(self) -> dict[int, tuple[int, list]]:
        """COB-ID -> (transmission type, entries) of the valid RPDOs."""
        out = {}
        for n in range(4):
            cob, valid, ttype, entries = pdo_config(self.node, 0x1400 + n, 0x1600 + n)
            if valid:
                out[cob] = (ttype, entries)
        return out

    def pdo_active(self) -> bool:
        return not self.silent and self.node.nmt.state == "OPERATIONAL"

    def on_rpdo_message(self, cob: int, data: bytearray, timestamp: float) -> None:
        """An RPDO frame (the controller subscribed its COB-ID); runs in the bus thread."""
        with self.arm._lock:
            self.on_rpdo(cob, bytes(data))

    def on_rpdo(self, cob: int, data: bytes) -> None:
        if not self.pdo_active() or cob not in self._rpdos:
            return
        ttype, entries = self._rpdos[cob]
        if len(data) < sum(bits for _, _, bits in entries) // 8:
            self.send_emcy(0x8210)  # PDO not processed due to length error
            return
        if ttype <= 240:
            self.sync_rpdos.append((entries, bytes(data)))
        else:
            self.apply_rpdo(entries, bytes(data))

    def apply_rpdo(self, entries: list, data: bytes) -> None:
        """Write every mapped object, the controlword last: a drive acts on the whole PDO at once."""
        values, offset = [], 0
        for index, sub, bits in entries:
            values.append((index == 0x6040, index, sub, data[offset:offset + bits // 8]))
            offset += bits // 8
        for _, index, sub, chunk in sorted(values, key=lambda v: v[0]):
            try:
                self.node.set_data(index, sub, chunk)
            except SdoAbortedError:
                pass

    def apply_sync_rpdos(self) -> None:
        pending, self.sync_rpdos = self.sync_rpdos, []
        for entries, data in pending:
            self.apply_rpdo(entries, data)

    def tpdo_frames(self, sync_count: int) -> list[tuple[int, bytes]]:
        """The TPDOs due at this SYNC (transmission types 1..240: every n-th SYNC)."""
        if not self.pdo_active() or self.stalled:
            return []
        frames = []
        for cob, valid, ttype, entries in self.tpdos():
            if valid and 1 <= ttype <= 240 and sync_count % ttype == 0:
                data = b"".join(self.node.get_data(i, s)[:bits // 8] for i, s, bits in entries)
                frames.append((cob, data[:5] if self.garbage else data))
        return frames
