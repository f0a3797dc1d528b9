"""How long the host kept this test process from running: the part of a measured stop latency that is not the agent's.

The safety tests bound a latency in wall time (the controller receives the stop within 0.5 s of a fault). On a
loaded machine (CI with both cores busy beside the other xdist worker) the scheduler can hold every thread of the
test process for hundreds of milliseconds, and the bound then measures the host, not the agent: a run in session
18 stopped 591 ms after the fault with two busy loops beside it, 200 ms of it the gap limit. Loosening the bound
would hide a slower agent on a quiet host as well; instead the host's share is measured and only it is excused.

A probe thread asks to wake every ``PERIOD_S`` and records each time it woke late. A late wake means that no
Python code of this process could run when it should (no free CPU, or the GIL held by a thread that had none), so
the lateness summed over a window is the wall time the process was stalled in it. A stop's path through the
driver's watchdog and the simulated controller waits through those same stalls. On a quiet host the sum is a few
milliseconds and the bound holds as written.

What it does not see: a controller in another process (the Modbus RTU device, ur-rtde's control worker) starved
at other moments than this one. Those tests keep their own margins.
"""

from __future__ import annotations

import threading
import time
from collections import deque

PERIOD_S = 0.002
LATE_S = 0.001  # a wake later than this is recorded; below it is timer slack, not a stall


class StallProbe:
    """A thread that measures, as wall-time intervals, when this process could not run on time."""

    def __init__(self, period_s: float = PERIOD_S) -> None:
        self.period_s = period_s
        self._late: deque[tuple[float, float]] = deque(maxlen=100_000)  # (due, woke), monotonic seconds
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stall-probe", daemon=True)

    def start(self) -> "StallProbe":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        due = time.monotonic() + self.period_s
        while not self._stop.is_set():
            time.sleep(max(0.0, due - time.monotonic()))
            woke = time.monotonic()
            if woke - due > LATE_S:
                self._late.append((due, woke))
            due = woke + self.period_s

    def stalled_s(self, t0: float, t1: float) -> float:
        """Wall time within [t0, t1] during which the probe was due but not running."""
        return sum(max(0.0, min(woke, t1) - max(due, t0)) for due, woke in list(self._late))


def assert_latency_within(latency_s: float, bound_s: float, probe: StallProbe, t0: float, what: str) -> None:
    """``latency_s`` from ``t0`` is within ``bound_s`` plus the time the host stalled this process meanwhile."""
    stalled = probe.stalled_s(t0, t0 + latency_s)
    assert latency_s - stalled < bound_s, (
        f"{what} {1000 * latency_s:.0f} ms after the fault, {1000 * stalled:.0f} ms of it the host stalling this "
        f"process: {1000 * (latency_s - stalled):.0f} ms against {1000 * bound_s:.0f} ms")
