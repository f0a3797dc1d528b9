"""What the driver knows about each drive, kept current from the CAN receive thread.

Every TPDO1 brings a drive's statusword and position; every heartbeat its NMT state; every EMCY
an error code. The callbacks only record (the receive thread must never block); the first
fault is kept as a sentence naming the joint, the node and the error code, and the driver's
threads act on it: the reader and the move loop trip the supervision, which quick-stops every
drive. A fault is:

- an emergency message (EMCY) with an error code other than 0x0000 (error reset);
- a heartbeat older than the consumer time (``heartbeat_timeout_ms``), or one reporting an NMT
  state other than OPERATIONAL, or a boot-up (the drive restarted);
- a drive that stops sending its TPDO while the others keep answering SYNC;
- a drive leaving OPERATION ENABLED while the driver expects it enabled;
- an SDO request (the driver's liveness poll, ``watch.SdoWatch``) left unanswered for longer than
  the reply limit while the drive kept answering SYNC with its TPDOs: its SDO server replies late
  or not at all. Counting the drive's TPDOs since the request, not only the time, keeps a pause of
  the agent's own process from looking like a late drive: the reply would have come before them.
"""

from __future__ import annotations

import functools
import threading
import time

from payload_agent.drivers.canopen.cia402 import FAULTY, OPERATION_ENABLED, describe_code, state_of
from payload_agent.drivers.canopen.options import CANopenOptions

NMT_OPERATIONAL, NMT_BOOTUP = 0x05, 0x00
NMT_NAMES = {0x00: "boot-up", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
HEARTBEAT_ERROR = 0x8130  # CiA 301 emergency code "life guard or heartbeat error"
SILENT_SYNCS = 5  # a drive missing this many SYNC answers in a row (and >= 20 ms) while the others answer
# an SDO request unanswered past the reply limit while the drive answered this many SYNCs after it: the drive is alive
# and its SDO server late. The receive thread handles frames in bus order, so a reply that came during a stall of the
# agent's own process is seen before the TPDOs behind it: a count, not a rate, which a loaded host would not reach
SDO_ALIVE_SYNCS = 10


class DriveMonitor:
    def __init__(self, opts: CANopenOptions):
        self.opts = opts
        n = len(opts.node_ids)
        self.labels = [opts.joint_label(j) for j in range(n)]
        self.statusword: list[int | None] = [None] * n
        self.position: list[int | None] = [None] * n
        self.seq = [0] * n  # TPDOs received per drive
        self.t_frame = [0.0] * n  # monotonic time of each drive's newest TPDO
        self.t_heartbeat: list[float | None] = [None] * n
        self.nmt_state: list[int | None] = [None] * n
        self.heartbeat_since: float | None = None  # consumer monitoring starts when 0x1017 was written
        self.expect_operational = False  # NMT start was sent
        self.operational = [False] * n  # a heartbeat reported OPERATIONAL since then
        self.expect_enabled = [False] * n  # the driver put the drive in OPERATION ENABLED
        self.emcy: list[tuple[int, int, int]] = []  # (joint, code, error register), every EMCY received
        self.sdo_pending: list[tuple[float, int] | None] = [None] * n  # (time of the request, seq then)
        self.sdo_reply_limit_s = 0.3  # the driver sets it from the supervision (max_reply_wait_s)
        self.fault: str | None = None
        self.drive_fault = False
        self._lock = threading.Lock()

    # -- from the receive thread -------------------------------------------------------------
    def on_frame(self, j: int, statusword: int, position: int, t_recv: float) -> None:
        self.statusword[j], self.position[j], self.t_frame[j] = statusword, position, t_recv
        self.seq[j] += 1
        if self.expect_enabled[j]:
            state = state_of(statusword)
            if state != OPERATION_ENABLED:
                code = self.last_emcy_code(j)
                self.set_fault(f"{self.labels[j]} left OPERATION ENABLED: it is now {state} (statusword "
                               f"0x{statusword:04X}), error code "
                               + (describe_code(code) if code is not None else "none reported (no EMCY)"),
                               drive_fault=True)

    def on_heartbeat(self, j: int, nmt_state: int) -> None:
        self.t_heartbeat[j] = time.monotonic()
        self.nmt_state[j] = nmt_state
        if nmt_state == NMT_OPERATIONAL:
            self.operational[j] = True
        elif self.expect_operational and self.operational[j]:  # it was OPERATIONAL (a heartbeat says so) and left
            what = "restarted (boot-up message)" if nmt_state == NMT_BOOTUP else \
                f"left NMT OPERATIONAL (heartbeat reports {NMT_NAMES.get(nmt_state, hex(nmt_state))})"
            self.set_fault(f"{self.labels[j]} {what}; its PDOs no longer run")

    def on_emcy(self, j: int, code: int, register: int) -> None:
        self.emcy.append((j, code, register))
        if code & 0xFF00 == 0:  # 0x00xx: error reset / no error
            return
        self.set_fault(f"EMCY from {self.labels[j]}: error code {describe_code(code)}, error register "
                       f"0x{register:02X}", drive_fault=True)

    def check_frame_lengths(self, network, j: int, node) -> None:
        """Length-check drive ``j``'s EMCY and heartbeat frames before canopen decodes them.

        canopen's decoders raise on a frame too short for its message (CiA 301: an EMCY has 8 data
        bytes, a heartbeat 1); its receive thread logs that and drops the frame, so the driver would
        never learn what the drive sent. Such a frame is a fault naming the drive instead.
        """
        for cob, what, decode, size_ok in ((0x80 + node.id, "EMCY", node.emcy.on_emcy, lambda n: n == 8),
                                           (0x700 + node.id, "heartbeat", node.nmt.on_heartbeat, lambda n: n >= 1)):
            network.unsubscribe(cob, decode)
            network.subscribe(cob, functools.partial(self._checked_frame, j, what, size_ok, decode))

    def _checked_frame(self, j: int, what: str, size_ok, decode, can_id: int, data: bytearray,
                       timestamp: float) -> None:
        if size_ok(len(data)):
            decode(can_id, data, timestamp)
            return
        self.set_fault(f"{self.labels[j]} sent a malformed {what}: {len(data)} data bytes "
                       f"({bytes(data).hex() or 'none'}) where CiA 301 has {8 if what == 'EMCY' else 1}",
                       drive_fault=what == "EMCY")

    def on_sdo_response(self, j: int) -> None:
        """Any SDO server reply from drive ``j`` (the receive thread: in bus order with its TPDOs)."""
        self.sdo_pending[j] = None

    def set_fault(self, text: str, drive_fault: bool = False) -> None:
        """Keep the first fault; ``drive_fault``: the drive itself stopped (EMCY, left OPERATION ENABLED),
        as opposed to the bus going quiet (heartbeat, PDO silence)."""
        with self._lock:
            if self.fault is None:
                self.fault = text
                self.drive_fault = drive_fault

    # -- from the driver's threads -----------------------------------------------------------
    def last_emcy_code(self, j: int) -> int | None:
        codes = [c for jj, c, _ in self.emcy if jj == j and c & 0xFF00]
        return codes[-1] if codes else None

    def check_silence(self, queued: list[int], period_s: float) -> None:
        """Heartbeat consumer and TPDO silence checks (cheap; call often)."""
        now = time.monotonic()
        if self.heartbeat_since is not None:
            limit = self.opts.heartbeat_timeout_ms / 1000.0
            for j, t in enumerate(self.t_heartbeat):
                last = t if t is not None else self.heartbeat_since
                if now - last > limit:
                    seen = "never" if t is None else f"none for {1000 * (now - t):.0f} ms"
                    self.set_fault(f"heartbeat lost from {self.labels[j]}: {seen} (consumer time "
                                   f"{self.opts.heartbeat_timeout_ms} ms), error code {describe_code(HEARTBEAT_ERROR)}")
        if self.expect_operational and max(queued, default=0) >= SILENT_SYNCS:
            limit = max(SILENT_SYNCS * period_s, 0.02)
            for j, n in enumerate(queued):
                if n == 0 and self.seq[j] and now - self.t_frame[j] > limit:
                    code = describe_code(HEARTBEAT_ERROR) if self._heartbeat_late(j, now) else "none reported"
                    self.set_fault(f"{self.labels[j]} stopped sending its TPDO: none for "
                                   f"{1000 * (now - self.t_frame[j]):.0f} ms while the other drives answered SYNC; "
                                   f"error code {code}")
        self._check_sdo(now, period_s)

    def sdo_requested(self, j: int) -> None:
        """The driver sends an SDO request to drive ``j`` now (call before sending it). An earlier request
        still unanswered keeps its time: the drive has owed an answer since then."""
        if self.sdo_pending[j] is None:
            self.sdo_pending[j] = (time.monotonic(), self.seq[j])

    def _check_sdo(self, now: float, period_s: float) -> None:
        limit = self.sdo_reply_limit_s
        syncs = SDO_ALIVE_SYNCS
        for j, pending in enumerate(self.sdo_pending):
            if pending is None:
                continue
            t, seq = pending
            if now - t > limit and self.seq[j] - seq >= syncs:
                self.set_fault(f"no SDO reply from {self.labels[j]} for {1000 * (now - t):.0f} ms (limit "
                               f"{1000 * limit:.0f} ms) while it answered {self.seq[j] - seq} SYNCs with its TPDO: "
                               "its SDO server replies late or not at all")

    def _heartbeat_late(self, j: int, now: float) -> bool:
        t = self.t_heartbeat[j]
        return t is None or now - t > 1.5 * self.opts.heartbeat_ms / 1000.0

    def states(self) -> list[str]:
        return [state_of(sw) if sw is not None else "no TPDO yet" for sw in self.statusword]

    def faulty(self) -> list[int]:
        return [j for j, s in enumerate(self.states()) if s in FAULTY]

    def pending(self, predicate, seq0: list[int], joints: list[int]) -> list[int]:
        """The joints in ``joints`` for which ``predicate(j, statusword)`` does not yet hold on a TPDO newer than
        ``seq0``."""
        return [j for j in joints if not (self.seq[j] > seq0[j] and self.statusword[j] is not None
                                          and predicate(j, self.statusword[j]))]

    def wait_for(self, predicate, seq0: list[int], joints: list[int], timeout_s: float, poll=None) -> list[int]:
        """Wait until ``predicate(j, statusword)`` holds for every joint in ``joints`` on a TPDO newer than
        ``seq0``; the joints for which it did not within ``timeout_s``. ``poll()`` runs every tick (it may raise)."""
        deadline = time.monotonic() + timeout_s
        pending = list(joints)
        while True:
            pending = self.pending(predicate, seq0, pending)
            if not pending or time.monotonic() > deadline:
                return pending
            if poll is not None:
                poll()
            time.sleep(0.002)
