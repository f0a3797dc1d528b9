"""PDO configuration of the drives, and the sample stream assembled from their TPDOs.

Every drive gets the same layout, written over SDO with the canopen library's PDO maps while
it is PRE-OPERATIONAL (CiA 301: a mapping changes only while its PDO is invalid):

- TPDO1, sent on every SYNC (transmission type 1): statusword 0x6041, position actual 0x6064,
  the effort object (0x6077 torque or 0x6078 current actual), 8 bytes;
- RPDO1, synchronous (type 1, acted on at the next SYNC): controlword 0x6040 + target position
  0x607A, so the set-points of all six drives take effect at the same SYNC;
- RPDO2, asynchronous (type 255, acted on at once): controlword 0x6040, for power state
  commands and the quick stop;
- RPDO3, synchronous: profile velocity 0x6081 + profile acceleration 0x6083; RPDO4, synchronous:
  profile deceleration 0x6084. A move's profile values go out in the same batch as its set-points
  and take effect at the same SYNC: no SDO transfer stands between a move and its start;
- every other PDO invalid.

``TpdoCollector`` keeps the TPDO1 frames per drive and hands out one set per SYNC once every
drive's frame for it has arrived (frames of one SYNC carry bus timestamps within a fraction of
a SYNC period of each other; an orphan whose partners never came is dropped and counted).
"""

from __future__ import annotations

import collections
import struct
import threading
import time
from dataclasses import dataclass

from canopen import RemoteNode

from payload_agent.drivers.canopen.objects import (CONTROLWORD, POSITION_ACTUAL, PROFILE_ACCELERATION,
                                                   PROFILE_DECELERATION, PROFILE_VELOCITY, STATUSWORD, TARGET_POSITION)

TPDO1 = struct.Struct("<Hih")  # statusword, position actual, effort actual (per mille)
RPDO_SETPOINT = struct.Struct("<Hi")  # controlword, target position
RPDO_COMMAND = struct.Struct("<H")  # controlword
RPDO_PROFILE = struct.Struct("<II")  # profile velocity, profile acceleration
RPDO_DECELERATION = struct.Struct("<I")  # profile deceleration
SYNCHRONOUS_EVERY_SYNC = 1
ASYNCHRONOUS = 255
# + node id (CiA 301 predefined connection set)
TPDO1_COB, RPDO1_COB, RPDO2_COB, RPDO3_COB, RPDO4_COB = 0x180, 0x200, 0x300, 0x400, 0x500


def _write_map(pdo_map, entries: tuple[int, ...], trans_type: int | None, enabled: bool) -> None:
    pdo_map.clear()
    for index in entries:
        pdo_map.add_variable(index)
    pdo_map.cob_id = pdo_map.predefined_cob_id
    pdo_map.trans_type = trans_type
    pdo_map.enabled = enabled
    pdo_map.save()  # SDO: invalidate, transmission type, mapping count 0, entries, count, valid again


def configure_pdos(node: RemoteNode, effort_index: int) -> None:
    """Write this driver's PDO layout to one drive (SDO; raises the canopen SDO errors)."""
    for n, pdo_map in node.tpdo.map.items():
        if n == 1:
            _write_map(pdo_map, (STATUSWORD, POSITION_ACTUAL, effort_index), SYNCHRONOUS_EVERY_SYNC, True)
        else:
            _write_map(pdo_map, (), None, False)
    for n, pdo_map in node.rpdo.map.items():
        if n == 1:
            _write_map(pdo_map, (CONTROLWORD, TARGET_POSITION), SYNCHRONOUS_EVERY_SYNC, True)
        elif n == 2:
            _write_map(pdo_map, (CONTROLWORD,), ASYNCHRONOUS, True)
        elif n == 3:
            _write_map(pdo_map, (PROFILE_VELOCITY, PROFILE_ACCELERATION), SYNCHRONOUS_EVERY_SYNC, True)
        elif n == 4:
            _write_map(pdo_map, (PROFILE_DECELERATION,), SYNCHRONOUS_EVERY_SYNC, True)
        else:
            _write_map(pdo_map, (), None, False)


@dataclass(frozen=True)
class Frame:
    timestamp: float  # the frame's bus timestamp (msg.timestamp)
    t_recv: float  # time.monotonic() at reception
    statusword: int
    position: int
    effort: int


class TpdoCollector:
    """Per-drive queues of TPDO1 frames, paired into one set per SYNC."""

    def __init__(self, n: int, maxlen: int = 4096):
        self.n = n
        self._queues: list[collections.deque[Frame]] = [collections.deque(maxlen=maxlen) for _ in range(n)]
        self._cond = threading.Condition()
        self._spacing: float | None = None  # bus-clock time between two SYNCs, learnt from the frames
        self._gaps: collections.deque[float] = collections.deque(maxlen=15)
        self._last_ts: float | None = None
        self.dropped = 0  # frames whose partners never arrived
        self.error: str | None = None  # a malformed frame: the stream is broken

    def push(self, j: int, frame: Frame) -> None:
        with self._cond:
            self._queues[j].append(frame)
            if all(self._queues):
                self._cond.notify()

    def fail(self, error: str) -> None:
        with self._cond:
            if self.error is None:
                self.error = error
            self._cond.notify()

    def queued(self, j: int) -> int:
        return len(self._queues[j])

    def pop_set(self, timeout_s: float) -> list[Frame] | None:
        """The frames of the next complete SYNC (one per drive, joint order), or None after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                if self.error is not None:
                    return None
                frames = self._take()
                if frames is not None:
                    return frames
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)

    def _take(self) -> list[Frame] | None:
        queues = self._queues
        while all(queues):
            heads = [q[0] for q in queues]
            newest = max(f.timestamp for f in heads)
            if self._spacing is not None:
                orphans = [q for q, f in zip(queues, heads) if f.timestamp < newest - 0.5 * self._spacing]
                if orphans:  # a frame from an earlier SYNC whose partners were lost
                    for q in orphans:
                        q.popleft()
                    self.dropped += len(orphans)
                    continue
            for q in queues:
                q.popleft()
            t = min(f.timestamp for f in heads)
            if self._last_ts is not None and t > self._last_ts:
                self._gaps.append(t - self._last_ts)
                self._spacing = sorted(self._gaps)[len(self._gaps) // 2]  # the median: robust to a missed SYNC
            self._last_ts = t
            return heads
        return None
