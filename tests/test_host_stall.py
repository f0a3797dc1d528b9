"""The stall probe measures a stall it did not cause: the whole process stopped from outside (SIGSTOP) for 0.4 s."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

CHILD = """
import json, sys, time
sys.path.insert(0, {tests!r})
from host_stall import StallProbe
probe = StallProbe().start()
time.sleep(0.2)
t0 = time.monotonic()
print("ready", flush=True)
sys.stdin.readline()  # the parent stops and continues this process meanwhile
t1 = time.monotonic()
time.sleep(0.05)
print(json.dumps({{"stalled": probe.stalled_s(t0, t1), "window": t1 - t0}}), flush=True)
"""


def test_a_process_stopped_from_outside_is_measured_as_stalled():
    code = CHILD.format(tests=str(Path(__file__).parent))
    child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        os.kill(child.pid, signal.SIGSTOP)
        time.sleep(0.4)
        os.kill(child.pid, signal.SIGCONT)
        child.stdin.write("go\n")
        child.stdin.flush()
        got = json.loads(child.stdout.readline())
    finally:
        child.kill()
        child.wait()
    # at least the 0.4 s it was stopped (a loaded host adds to it), never more than the window it is asked about
    assert 0.38 <= got["stalled"] <= got["window"], got
