"""How much of the simulated UR's RTDE stream each way of reading it keeps, on this host as it is loaded now.

Not a test: it prints numbers (docs/benchmarks.md, session 14). The simulated UR (``fakes/ur``) runs in its own
process and sends one package per control cycle of simulated time (500 Hz; ``--time-scale`` times as many per
wall second); its count of packages sent is compared with what three readers got over the same seconds:

* ``driver``: the UR driver's sample stream (``drivers/ur_rtde/sample_reader.py``: package by package from an
  RTDE connection of its own), delivered + missed (from the controller timestamps);
* ``poll``: ur_rtde's ``RTDEReceiveInterface`` polled from Python for a new timestamp, as the driver read it
  before session 14 (it keeps only the newest package);
* ``file``: ur_rtde's ``startFileRecording`` (its recorder thread copies the newest state once per period):
  rows written and distinct timestamps among them.

    nice -n 10 .venv/bin/python -m benchmarks.ur_stream [--seconds 3] [--time-scale 5] [--gil-busy]

``--gil-busy``: a pure-Python thread beside the readers holds the interpreter as a run's other threads do.
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from payload_agent.drivers.base import MotionLimits, Supervision
from payload_agent.drivers.ur_rtde.driver import URRTDEDriver
from payload_agent.fakes.ur import FakeURController

LIMITS = MotionLimits(max_joint_speed_rad_s=3.0, max_joint_accel_rad_s2=40.0)
PERIOD_S = 0.002  # the simulated e-Series' control cycle


class _Busy:
    """A pure-Python loop on a thread of this process while it is entered (``--gil-busy``)."""

    def __init__(self, on: bool):
        self.on, self._stop = on, threading.Event()

    def __enter__(self):
        if self.on:
            threading.Thread(target=self._spin, daemon=True).start()
        return self

    def _spin(self):
        while not self._stop.is_set():
            sum(i * i for i in range(2000))

    def __exit__(self, *exc):
        self._stop.set()


def kept(ts: np.ndarray) -> tuple[int, float]:
    """(distinct packages, their share of those due over their span)."""
    u = np.unique(ts)
    return len(u), len(u) / (round((u[-1] - u[0]) / PERIOD_S) + 1)


def driver(ur, seconds: float, busy: bool) -> str:
    d = URRTDEDriver(URRTDEDriver.parse_options({"type": "ur_rtde", "host": ur.host}), LIMITS,
                     Supervision(max_stream_gap_s=1.0, max_reply_wait_s=2.0))
    d.connect()
    try:
        time.sleep(0.3)
        samples: list = []
        sent0, deliv0, missed0 = ur.stream_packages_sent, d.samples_delivered, d.samples_missed
        with _Busy(busy):
            d.start_stream(samples.append)
            time.sleep(seconds)
            d.stop_stream()
        sent = (ur.stream_packages_sent - sent0) / 2  # two sample sessions: the driver's and ur_rtde's receive
        deliv, missed = d.samples_delivered - deliv0, d.samples_missed - missed0
    finally:
        d.close()
    n, share = kept(np.array([s.t_ctrl for s in samples]))
    return (f"driver (own RTDE connection): {deliv} delivered + {missed} missed = {deliv + missed}, the fake sent "
            f"≈ {sent:.0f} to each sample session; kept {100 * share:.1f} %")


def poll(ur, seconds: float, busy: bool) -> str:
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "actual_q", "actual_current"], False, False)
    try:
        time.sleep(0.3)
        ts, last = [], None
        sent0 = ur.stream_packages_sent
        end = time.monotonic() + seconds
        with _Busy(busy):
            while time.monotonic() < end:
                t = r.getTimestamp()
                if t != last:
                    r.getActualQ(), r.getActualCurrent()
                    ts.append(t)
                    last = t
                else:
                    time.sleep(0.0002)
        sent = ur.stream_packages_sent - sent0
    finally:
        r.disconnect()
    n, share = kept(np.array(ts))
    return f"poll (ur_rtde's receive interface from Python): {n} of the {sent} sent; kept {100 * share:.1f} %"


def file(ur, seconds: float, busy: bool) -> str:
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(ur.host, 500.0, ["timestamp", "actual_q", "actual_current"], False, False)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rec.csv"
        try:
            time.sleep(0.3)
            sent0 = ur.stream_packages_sent
            with _Busy(busy):
                r.startFileRecording(str(path), ["timestamp", "actual_current"])
                time.sleep(seconds)
                r.stopFileRecording()
            sent = ur.stream_packages_sent - sent0
        finally:
            r.disconnect()
        with path.open() as f:
            ts = np.array([float(row[0]) for row in list(csv.reader(f))[1:]])
    n, share = kept(ts)
    return (f"file (ur_rtde's startFileRecording): {len(ts)} rows, {n} distinct of the {sent} sent, "
            f"{len(ts) - n} duplicates; kept {100 * share:.1f} %")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--time-scale", type=float, default=5.0, help="simulated seconds per wall second (sim-ur5e: 5)")
    ap.add_argument("--gil-busy", action="store_true", help="a pure-Python thread beside the readers")
    args = ap.parse_args(argv)
    with open("/proc/loadavg") as f:
        load = f.read().split()[0]
    print(f"{args.seconds:g} s at time_scale {args.time_scale:g} ({500 * args.time_scale:.0f} packages per wall "
          f"second), load {load}{', a busy Python thread' if args.gil_busy else ''}:", flush=True)
    with FakeURController(time_scale=args.time_scale) as ur:
        for read in (driver, poll, file):
            print("  " + read(ur, args.seconds, args.gil_busy), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
