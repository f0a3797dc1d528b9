"""How the agent and its drives watch each other beyond the PDO stream.

Two directions, because a CAN bus can fail in either:

- **The drives watch the agent** (``configure_master_watch``). The agent produces a heartbeat
  (``bus.SyncProducer``, COB-ID 0x700 + ``master_node_id``) and writes every drive's consumer
  heartbeat time (CiA 301 object 0x1016: node id in bits 16-23, time in ms in bits 0-15) and its
  abort connection option code (CiA 402 object 0x6007 = 3: quick stop). A drive that hears no
  heartbeat from the agent for longer than the consumer time stops itself: when the bus is cut
  between the agent and the drives, or the agent's process dies, no quick stop the agent sends
  could reach them (docs/sources.md, "CANopen: the drives watch the master").
- **The agent watches the drives' SDO servers** (``SdoWatch``). SDO is used for configuration
  only, but a drive whose SDO server stops answering while its PDOs still run has a
  communication stack in trouble: its stop confirmation, its error code and the next enable
  would not come either. A thread reads each drive's error register (0x1001, mandatory in every
  CiA 301 device) in turn, one request every ``POLL_INTERVAL_S``; the drive monitor judges a
  request unanswered for longer than the supervision's reply limit (``max_reply_wait_s``) while
  the drive kept answering SYNC as a fault, which trips the supervision (every drive is
  quick-stopped). Before a move's set-points go out, ``confirm_alive`` waits for one answered
  request per drive issued after the move was asked for: a late SDO server trips before any
  set-point, never after.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Callable

import can
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from payload_agent.drivers.canopen import objects as obj
from payload_agent.errors import CommunicationError

if TYPE_CHECKING:
    from payload_agent.drivers.canopen.driver import CANopenDriver

log = logging.getLogger(__name__)

QUICK_STOP_ON_ABORT = 3  # 0x6007: 0 no action, 1 fault signal, 2 disable voltage, 3 quick stop
ABORT_NO_OBJECT, ABORT_NO_SUBINDEX = 0x06020000, 0x06090011
POLL_INTERVAL_S = 0.02  # between two liveness requests (each drive every n x this)
GATE_TIMEOUT_S = 2.0  # confirm_alive's last resort (the monitor's judgement trips long before, if PDOs run)


def _abort_code(exc: CommunicationError) -> int | None:
    cause = exc.__cause__
    return cause.code if isinstance(cause, SdoAbortedError) else None


def configure_master_watch(drv: "CANopenDriver", j: int) -> str | None:
    """Make drive ``j`` consume the agent's heartbeat and quick-stop when it is lost; a note if it cannot fully."""
    o = drv.options
    if not o.master_heartbeat_ms:
        return None
    label = drv.labels[j]
    entry = o.master_node_id << 16 | o.master_heartbeat_timeout_ms
    try:
        count = int(drv.sdo_read(j, obj.CONSUMER_HEARTBEAT, 0))
    except CommunicationError as exc:
        if _abort_code(exc) not in (ABORT_NO_OBJECT, ABORT_NO_SUBINDEX):
            raise
        raise CommunicationError(f"{label} has no consumer heartbeat time (0x1016): it cannot stop itself when "
                                 "it loses the agent (bus cut, agent killed). Set driver.master_heartbeat_ms: 0 to "
                                 "run without that protection") from exc
    sub = None
    for k in range(1, count + 1):  # the entry that watches the agent already, else the first free one
        value = int(drv.sdo_read(j, obj.CONSUMER_HEARTBEAT, k))
        node = value >> 16 & 0xFF
        if node == o.master_node_id:
            sub = k
            break
        if sub is None and (node == 0 or value & 0xFFFF == 0):
            sub = k
    if sub is None:
        raise CommunicationError(f"{label}: every consumer heartbeat entry (0x1016 sub 1..{count}) watches another "
                                 f"node; none is free for the agent (node {o.master_node_id})")
    drv.sdo_write(j, obj.CONSUMER_HEARTBEAT, entry, sub=sub)
    try:
        drv.sdo_write(j, obj.ABORT_CONNECTION, QUICK_STOP_ON_ABORT)
    except CommunicationError as exc:
        if _abort_code(exc) != ABORT_NO_OBJECT:
            raise
        note = (f"{label} has no abort connection option code (0x6007): what it does when it loses the agent's "
                "heartbeat is its own setting (see its manual)")
        log.warning("%s", note)
        return note
    return None


class SdoWatch:
    """Round-robin SDO liveness requests to every drive, from connect to close (see the module docstring)."""

    def __init__(self, drv: "CANopenDriver"):
        self.drv = drv
        self.answered_t = [0.0] * drv.n  # request time of each drive's newest answered request
        self._running = threading.Event()
        self._hurry = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "SdoWatch":
        self._running.set()
        self._thread = threading.Thread(target=self._run, name="canopen-sdo-watch", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running.clear()
        self._hurry.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=self.drv.options.sdo_timeout_s + 0.5)
        self._thread = None

    def confirm_alive(self, poll: Callable[[], None]) -> None:
        """Return once every drive answered an SDO request sent after this call; ``poll()`` runs first and then
        while waiting, and raises on a trip (or a pending drive fault). Before set-points go out, and before the
        power stages are enabled: a drive whose SDO server is gone could neither report its error code nor
        confirm a stop over SDO."""
        t0 = time.monotonic()
        deadline = t0 + max(GATE_TIMEOUT_S, 2 * (self.drv.options.sdo_timeout_s + self.drv.monitor.sdo_reply_limit_s))
        self._hurry.set()
        try:
            while True:
                poll()  # the monitor's judgement: a drive alive on PDO but late on SDO trips the supervision
                late = [j for j, t in enumerate(self.answered_t) if t < t0]
                if not late:
                    return
                if time.monotonic() > deadline:
                    raise CommunicationError(f"{self.drv.labels[late[0]]} did not answer an SDO request within "
                                             f"{deadline - t0:.2f} s before the move; no set-point was sent")
                time.sleep(0.002)
        finally:
            self._hurry.clear()

    def _run(self) -> None:
        j = 0
        while self._running.is_set():
            self._ask(j)
            j = (j + 1) % self.drv.n
            if not self._hurry.is_set():
                self._hurry.wait(POLL_INTERVAL_S)

    def _ask(self, j: int) -> None:
        drv, monitor = self.drv, self.drv.monitor
        lock = drv._sdo_locks[j]
        if not lock.acquire(blocking=False):
            return  # another transfer uses the drive's SDO channel: it proves (or disproves) the same
        client = drv.nodes[j].sdo
        t = time.monotonic()
        answered = False
        try:
            client.RESPONSE_TIMEOUT = drv.options.sdo_timeout_s
            monitor.sdo_requested(j)
            client.upload(obj.ERROR_REGISTER, 0)  # its value is the EMCYs' business; the answer is what counts
            answered = True
        except SdoAbortedError:
            answered = True  # an abort is an answer
        except (SdoCommunicationError, can.CanError, OSError, AttributeError):
            pass  # no answer: the monitor has judged it (PDOs alive) or the stream watchdog will (bus gone)
        except Exception as exc:  # noqa: BLE001 - a malformed reply (canopen's decoder raised): not an answer,
            log.debug("SDO liveness request to %s: %s: %s", drv.labels[j], type(exc).__name__, exc)  # keep watching
        finally:
            if answered:  # an unanswered request stays owed: only a reply clears it (on_sdo_response)
                monitor.sdo_pending[j] = None
            lock.release()
        if answered:
            self.answered_t[j] = t
