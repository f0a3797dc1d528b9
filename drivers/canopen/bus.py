"""The CAN side of the driver: opening a python-can bus, the SYNC producer, and a quick stop on a new bus.

The SYNC producer is the driver's own thread rather than canopen's ``SyncProducer`` (a bare
periodic frame) because a CiA 301 master sends its synchronous RPDOs right after a SYNC, inside
the synchronous window: a batch queued with ``after_next_sync`` goes out together right after
one SYNC, so every drive acts on it at the same following SYNC. The same thread produces the
agent's own heartbeat (COB-ID 0x700 + ``master_node_id``, NMT state OPERATIONAL) that every drive
consumes (0x1016): a master whose cyclic task stops, or a bus cut between it and the drives,
silences both, and each drive stops itself once the heartbeat is older than its consumer time.
Sent before the SYNC it is due with, never behind a late one.

``quick_stop_on_new_bus`` is the supervision's stop when the driver's own bus object is gone: a
new python-can bus on the same interface and channel sends the quick stop controlword to every
drive and reads their statuswords (from their TPDOs, else by expedited SDO upload) to confirm.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Iterable

import can

from payload_agent.drivers.canopen.cia402 import CW_QUICK_STOP, state_of, stopped
from payload_agent.drivers.canopen.objects import STATUSWORD
from payload_agent.drivers.canopen.options import CANopenOptions
from payload_agent.drivers.canopen.pdo import RPDO2_COB, RPDO_COMMAND, TPDO1_COB
from payload_agent.errors import CommunicationError

SYNC_COB = 0x080
HEARTBEAT_COB = 0x700
NMT_OPERATIONAL = b"\x05"
SDO_REQUEST_COB, SDO_RESPONSE_COB = 0x600, 0x580
_SDO_UPLOAD = struct.Struct("<BHB4x")  # ccs=2 initiate upload request: command, index, sub-index


def bus_arguments(opts: CANopenOptions) -> dict:
    channel: str | int = opts.channel
    if isinstance(channel, str) and channel.isdigit():
        channel = int(channel)  # kvaser, ixxat, vector, ... number their channels
    return {"interface": opts.interface, "channel": channel, "bitrate": opts.bitrate}


def another_master(network, window_s: float) -> str | None:
    """Listen, sending nothing, for a SYNC from someone else: another master (a second session, the cell's
    controller) drives these drives now, and a second master's NMT, SDO or power-stage commands would stop
    or upset its motion. Returns what was heard, or None when the bus carried no SYNC for ``window_s``."""
    heard: list[float] = []
    callback = lambda can_id, data, timestamp: heard.append(time.monotonic())  # noqa: E731
    network.subscribe(SYNC_COB, callback)
    try:
        deadline = time.monotonic() + window_s
        while not heard and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        network.unsubscribe(SYNC_COB, callback)
    if not heard:
        return None
    return (f"another CANopen master is active on the bus: SYNC frames (COB-ID 0x{SYNC_COB:03X}) arrive from "
            "someone else. Wait until that session or controller has finished and released the drives; this "
            "session sent nothing on the bus")


def open_bus(opts: CANopenOptions) -> can.BusABC:
    """A python-can bus for the YAML's interface and channel; CommunicationError says which failed."""
    try:
        return can.Bus(**bus_arguments(opts))
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise CommunicationError(f"cannot open the CAN interface {opts.interface!r} channel {opts.channel!r}: "
                                 f"{type(exc).__name__}: {exc}. Check driver.interface / driver.channel, that the "
                                 "adapter is plugged in and the link is up (socketcan: ip link set can0 up type can "
                                 "bitrate 1000000).") from exc


class SyncProducer:
    """SYNC at a fixed rate from its own thread; frames queued with ``after_next_sync`` follow one SYNC."""

    def __init__(self, send, period_s: float, heartbeat_node: int | None = None, heartbeat_s: float = 0.0):
        self._send = send  # send(cob_id, data)
        self.period_s = float(period_s)
        self._heartbeat_cob = None if heartbeat_node is None or heartbeat_s <= 0 else HEARTBEAT_COB + heartbeat_node
        self.heartbeat_s = float(heartbeat_s)
        self.heartbeats = 0
        self._after: list[tuple[int, bytes]] = []
        self._lock = threading.Lock()
        self._running = threading.Event()
        self._thread: threading.Thread | None = None
        self.count = 0
        self.error: BaseException | None = None

    def start(self) -> "SyncProducer":
        self._running.set()
        self._thread = threading.Thread(target=self._run, name="canopen-sync", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running.clear()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._thread = None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive() and self.error is None

    def after_next_sync(self, frames: Iterable[tuple[int, bytes]]) -> None:
        with self._lock:
            self._after.extend(frames)

    def cancel_pending(self) -> None:
        with self._lock:
            self._after = []

    def _run(self) -> None:
        next_t = next_heartbeat = time.monotonic()
        while self._running.is_set():
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            with self._lock:
                batch, self._after = self._after, []
            try:
                now = time.monotonic()
                if self._heartbeat_cob is not None and now >= next_heartbeat:
                    self._send(self._heartbeat_cob, NMT_OPERATIONAL)
                    self.heartbeats += 1
                    next_heartbeat = max(next_heartbeat + self.heartbeat_s, now)
                self._send(SYNC_COB, b"")
                for cob_id, data in batch:
                    self._send(cob_id, data)
            except Exception as exc:  # the bus is broken: the supervision sees SYNC (and TPDOs) stop
                self.error = exc
                return
            self.count += 1
            next_t += self.period_s
            if time.monotonic() - next_t > self.period_s:  # fell behind: no burst of SYNCs, carry on from now
                next_t = time.monotonic()


def statusword_from(msg: can.Message, node_ids: set[int]) -> tuple[int, int] | None:
    """(node id, statusword) from a TPDO1 or an expedited SDO upload reply of 0x6041, else None."""
    cob, data = msg.arbitration_id, msg.data
    if TPDO1_COB < cob <= TPDO1_COB + 127 and cob - TPDO1_COB in node_ids and len(data) >= 2:
        return cob - TPDO1_COB, data[0] | data[1] << 8
    if SDO_RESPONSE_COB < cob <= SDO_RESPONSE_COB + 127 and cob - SDO_RESPONSE_COB in node_ids and len(data) == 8:
        if data[0] & 0xE3 == 0x43 and (data[1] | data[2] << 8) == STATUSWORD:  # expedited upload response
            return cob - SDO_RESPONSE_COB, data[4] | data[5] << 8
    return None


def quick_stop_on_new_bus(opts: CANopenOptions, node_ids: Iterable[int], wait_s: float) -> set[int]:
    """Quick stop every drive over a new bus object; the node ids that confirmed they stopped."""
    wanted = set(node_ids)
    confirmed: set[int] = set()
    bus = open_bus(opts)
    try:
        for nid in sorted(wanted):
            bus.send(can.Message(arbitration_id=RPDO2_COB + nid, data=RPDO_COMMAND.pack(CW_QUICK_STOP),
                                 is_extended_id=False))
        deadline = time.monotonic() + wait_s
        asked_sdo = False
        while confirmed != wanted:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            if not asked_sdo and remaining < wait_s / 2:  # no TPDO confirmed them: ask over SDO
                for nid in sorted(wanted - confirmed):
                    bus.send(can.Message(arbitration_id=SDO_REQUEST_COB + nid,
                                         data=_SDO_UPLOAD.pack(0x40, STATUSWORD, 0), is_extended_id=False))
                asked_sdo = True
            msg = bus.recv(timeout=min(remaining, 0.01))
            got = None if msg is None else statusword_from(msg, wanted)
            if got is not None and stopped(state_of(got[1])):
                confirmed.add(got[0])
    finally:
        bus.shutdown()
    return confirmed
