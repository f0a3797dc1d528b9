"""The sample stream every driver has: a reader thread beside the connection (as python-can's
``Notifier`` sits beside its bus).

From ``start()`` to ``stop()`` a thread calls the driver's ``_read_sample`` hook, checks every
sample (joint count, finite values), keeps the newest, hands each to the sink and adds it to the
per-sweep statistics. When a read raises, the stream keeps the reason (``error``) and tells the
supervision (``on_failure``), which stops an arm that is moving; it never reads again.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable

from payload_agent.errors import CommunicationError, PayloadAgentError
from payload_agent.types import Sample, StreamStats

SampleSink = Callable[[Sample], None]

READ_TIMEOUT_S = 0.05  # how long one _read_sample call may block


class SampleStream:
    """The newest sample, the sink, the statistics and the reader thread of one driver."""

    def __init__(self, read: Callable[[float], Sample | None], n_joints: int, name: str,
                 gap_limit_s: Callable[[], float], on_failure: Callable[[str], None]):
        self._read = read
        self._n = n_joints
        self._name = name
        self._gap_limit_s = gap_limit_s
        self._on_failure = on_failure
        self._sink: SampleSink | None = None
        self._sink_lock = threading.Lock()
        self._stats: StreamStats | None = None
        self._stats_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self.latest: Sample | None = None
        self.error: BaseException | None = None

    # -- life cycle -----------------------------------------------------------------------------
    def start(self) -> None:
        """Forget the last connection's samples and failure; start reading."""
        self.error = None
        self.latest = None
        self._running.set()
        self._thread = threading.Thread(target=self._loop, name=f"{self._name}-stream", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop reading (waits for the reader thread, unless called from it). Never raises."""
        self._running.clear()
        with self._sink_lock:
            self._sink = None
        th, self._thread = self._thread, None
        if th is not None and th is not threading.current_thread():
            th.join(timeout=2.0)

    # -- consumers ------------------------------------------------------------------------------
    def set_sink(self, sink: SampleSink | None) -> None:
        with self._sink_lock:
            self._sink = sink

    def begin_stats(self, nominal_period_s: float) -> None:
        with self._stats_lock:
            self._stats = StreamStats(nominal_period_s=nominal_period_s)

    def end_stats(self) -> StreamStats | None:
        with self._stats_lock:
            stats, self._stats = self._stats, None
        return stats

    def wait(self, timeout_s: float, after: float | None, endpoint: str) -> Sample:
        """The newest sample (received after ``after``, monotonic, if given); CommunicationError on none."""
        deadline = time.monotonic() + timeout_s
        while True:
            s = self.latest
            if s is not None and (after is None or s.t_recv > after):
                return s
            if self.error is not None:
                raise CommunicationError(f"the sample stream ended: {self.error}")
            if time.monotonic() > deadline:
                raise CommunicationError(f"no joint sample from the {self._name} controller ({endpoint}) for "
                                         f"{timeout_s:.1f} s")
            time.sleep(0.002)

    # -- the reader thread ----------------------------------------------------------------------
    def _loop(self) -> None:
        while self._running.is_set():
            try:
                sample = self._read(READ_TIMEOUT_S)
                if sample is None:
                    continue
                check_sample(sample, self._n)
            except Exception as exc:  # the stream is broken: keep the reason, trip any armed move
                if not self._running.is_set():
                    return
                self.error = exc if isinstance(exc, PayloadAgentError) else CommunicationError(
                    f"the sample stream failed: {type(exc).__name__}: {exc}")
                self._on_failure(f"the sample stream failed: {self.error}")
                return
            self._deliver(sample)

    def _deliver(self, sample: Sample) -> None:
        self.latest = sample
        with self._stats_lock:
            if self._stats is not None:
                self._stats.add(sample.t_recv, sample.t_ctrl, self._gap_limit_s())
        with self._sink_lock:
            sink = self._sink
            if sink is not None:
                sink(sample)


def check_sample(sample: Sample, n: int) -> None:
    """CommunicationError for a sample with the wrong number of joints or a non-finite value."""
    if len(sample.q) != n or len(sample.effort) != n:
        raise CommunicationError(f"a sample has {len(sample.q)} angles and {len(sample.effort)} efforts, expected {n}")
    if not (all(math.isfinite(v) for v in sample.q) and all(math.isfinite(v) for v in sample.effort)):
        raise CommunicationError(f"the controller sent a non-finite value: q={list(sample.q)}, "
                                 f"effort={list(sample.effort)}")
