"""Triggered recalibration loop (agent/watch.py) and the Elite driver's digital input against the fake."""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from dataclasses import replace

import pytest
import yaml

from conftest import ROOT
from payload_agent.configuration.config import parse_config
from payload_agent.configuration.watch import WatchConfig
from payload_agent.errors import CommunicationError, ConfigError, MotionAbortedError, UnsupportedCapability
from payload_agent.session.watch import watch

POLL = 0.01


@pytest.fixture(scope="module")
def base_cfg():
    return parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()))


def file_cfg(base, path):
    return replace(base, watch=WatchConfig("file", path, None, POLL))


def input_cfg(base, index=3):
    return replace(base, watch=WatchConfig("digital_input", None, index, POLL))


class Log(list):
    def __call__(self, line: str) -> None:
        self.append(line)


def test_file_trigger_one_file_one_run(base_cfg, tmp_path):
    trig = tmp_path / "go"
    calls = []
    log = Log()

    def run_once() -> int:
        assert not trig.exists(), "the trigger file must be consumed before the run starts"
        calls.append(time.monotonic())
        if len(calls) == 1:
            trig.write_text("gripper-B")  # a trigger arriving during the run: one more run afterwards
        return 0 if len(calls) == 1 else 5

    trig.write_text("gripper-A\n")
    code = watch(file_cfg(base_cfg, trig), run_once, out=log, max_runs=2)
    assert len(calls) == 2 and code == 5 and not trig.exists()
    text = "\n".join(log)
    assert "'gripper-A'" in text and "'gripper-B'" in text
    assert "run 1 finished: exit code 0 (success)" in text
    assert "run 2 finished: exit code 5 (data or quality failure)" in text
    assert all(line[:4].isdigit() and "T" in line[:20] for line in log)  # every line starts with a timestamp


def test_stop_event_ends_the_wait(base_cfg, tmp_path):
    stop = threading.Event()
    threading.Timer(0.1, stop.set).start()
    t0 = time.monotonic()
    code = watch(file_cfg(base_cfg, tmp_path / "never"), lambda: 1 / 0, stop_event=stop, out=Log())
    assert code == 0 and time.monotonic() - t0 < 2.0


def test_sigterm_while_waiting_returns_cleanly_and_restores_handlers(base_cfg, tmp_path):
    before = signal.getsignal(signal.SIGTERM)
    log = Log()
    threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGTERM)).start()
    code = watch(file_cfg(base_cfg, tmp_path / "never"), lambda: 1 / 0, out=log)
    assert code == 0
    assert "stopped (signal SIGTERM) after 0 run(s)" in log[-1]
    assert signal.getsignal(signal.SIGTERM) is before


SIGNAL_INSIDE_WAIT = """
import signal, sys, threading
from dataclasses import replace
import yaml
from payload_agent.configuration.config import parse_config
from payload_agent.configuration.watch import WatchConfig
from payload_agent.session.watch import watch

class SignalInsideWait(threading.Event):
    # SIGTERM arrives while wait() holds the event's own lock: the handler runs in this thread right there
    def wait(self, timeout=None):
        with self._cond:
            signal.raise_signal(signal.SIGTERM)
        return super().wait(timeout)

cfg = parse_config(yaml.safe_load(open(sys.argv[1]).read()))
cfg = replace(cfg, watch=WatchConfig("file", sys.argv[2], None, 0.01))
sys.exit(watch(cfg, lambda: 1 / 0, stop_event=SignalInsideWait()))
"""


def test_sigterm_while_the_wait_holds_its_lock_still_ends_the_watch(tmp_path):
    """The handler must take no lock: Event.set() there waits for the event's lock, which the main thread holds
    inside Event.wait() at that moment, for ever (a watch once ignored SIGTERM for 30 s in CI this way). In a
    child process, so that a regression fails by the timeout instead of hanging the suite."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", SIGNAL_INSIDE_WAIT, str(ROOT / "configs" / "sim-ec66.yaml"),
                           str(tmp_path / "never")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "stopped (signal SIGTERM) after 0 run(s)" in done.stdout


def test_sigterm_during_a_run_takes_the_abort_path(base_cfg, tmp_path):
    """The signal becomes KeyboardInterrupt inside the run (the runner stops the robot there); a second
    signal while the run is stopping does not raise again; the loop ends with the run's exit code."""
    trig = tmp_path / "go"
    trig.touch()
    events = []

    def run_once() -> int:  # shaped like the runner: Ctrl-C -> stop robot -> MotionAbortedError
        try:
            threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGTERM)).start()
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                time.sleep(0.005)  # "moving"
            events.append("motion finished (must not happen)")
            return 0
        except KeyboardInterrupt:
            events.append("robot stopped")
            os.kill(os.getpid(), signal.SIGTERM)  # impatient supervisor: must not interrupt the stop
            time.sleep(0.05)
            events.append("data kept")
            raise MotionAbortedError("interrupted; the robot was stopped") from None

    log = Log()
    code = watch(file_cfg(base_cfg, trig), run_once, out=log)
    assert events == ["robot stopped", "data kept"]
    assert code == 4  # MotionAbortedError's exit code
    assert any("SIGTERM again" in line for line in log)
    assert "stopped (signal SIGTERM) after 1 run(s)" in log[-1]


class FakeInputDriver:
    """Digital input levels from a script; counts connections."""

    def __init__(self, levels, fail_first=0):
        self.levels = list(levels)
        self.fail_first = fail_first
        self.connects = 0
        self.closed = 0

    def __call__(self):  # the factory
        return self

    def connect(self):
        self.connects += 1
        if self.fail_first:
            self.fail_first -= 1
            raise CommunicationError("controller unreachable")

    def close(self):
        self.closed += 1

    def read_digital_input(self, index):
        assert index == 3
        return self.levels.pop(0) if len(self.levels) > 1 else self.levels[0]


def test_digital_input_rising_edges_only(base_cfg):
    # high at start (no trigger), high, low, high (run 1); still high after the run, high, low, low, high (run 2)
    drv = FakeInputDriver([1, 1, 0, 1, 1, 1, 0, 0, 1], fail_first=1)
    calls = []
    log = Log()
    code = watch(input_cfg(base_cfg), lambda: calls.append(len(drv.levels)) or 0, driver_factory=drv, out=log,
                 max_runs=2)
    assert code == 0 and len(calls) == 2
    assert calls == [5, 1]  # levels left when each run started: edges at the 4th and 9th reading
    assert drv.connects == 3  # 1 failed + 1 before run 1 + 1 after it (closed while the run has the robot)
    assert any("cannot read digital input 3" in line and "retrying" in line for line in log)
    assert any("digital input 3 went high" in line for line in log)


class CodedInputDriver(FakeInputDriver):
    """The trigger input 3 from a script; the tool number on inputs 8, 9, 10 (LSB first) from a list per edge."""

    def __init__(self, levels, numbers):
        super().__init__(levels)
        self.numbers = list(numbers)
        self.coded_reads = []

    def read_digital_input(self, index):
        if index == 3:
            return self.levels.pop(0) if len(self.levels) > 1 else self.levels[0]
        bit = index - 8
        assert 0 <= bit < 3, index
        self.coded_reads.append(index)
        return bool((self.numbers[0] >> bit) & 1)


def test_digital_input_edge_carries_the_tool_number_on_coded_inputs(base_cfg):
    # edges at the 2nd and 5th reading; the tool changer codes tool 5 (101), then 0 (no tool named)
    drv = CodedInputDriver([0, 1, 1, 0, 1], numbers=[5, 0])
    tools, log = [], Log()

    def run_tool(name):
        tools.append(name)
        drv.numbers.pop(0)
        return 0

    cfg = replace(base_cfg, watch=WatchConfig("digital_input", None, 3, POLL, tool_inputs=(8, 9, 10)))
    code = watch(cfg, lambda: 1, driver_factory=drv, out=log, max_runs=2, run_tool=run_tool)
    assert code == 0 and tools == ["5", None]
    assert drv.coded_reads == [8, 9, 10, 8, 9, 10]  # read once per edge, never while waiting
    assert any("digital input 3 went high; tool number 5" in line for line in log)
    assert any("no tool number (inputs all low)" in line for line in log)


def test_unsupported_driver_and_missing_section(base_cfg, tmp_path):
    class NoInputs(FakeInputDriver):
        def read_digital_input(self, index):
            raise UnsupportedCapability("driver 'x' cannot read digital inputs")

    with pytest.raises(UnsupportedCapability):
        watch(input_cfg(base_cfg), lambda: 0, driver_factory=NoInputs([0]), out=Log())
    with pytest.raises(ConfigError, match="no watch section"):
        watch(replace(base_cfg, watch=None), lambda: 0, out=Log())
    with pytest.raises(ConfigError, match="driver_factory"):
        watch(input_cfg(base_cfg), lambda: 0, out=Log())


# -- the real driver against the Elite fake ---------------------------------------------------
@pytest.fixture
def elite():
    pytest.importorskip("mujoco")
    from payload_agent.fakes.arms import ec66_spec
    from payload_agent.fakes.elite_ec import FakeEliteController
    from payload_agent.fakes.sim_robot import SimRobot

    robot = SimRobot(ec66_spec(), q0_rad=[0.0, -math.pi / 2, math.pi / 2, 0.0, math.pi / 2, 0.0], tick_s=0.008,
                     time_scale=20.0)
    robot.start()
    ctrl = FakeEliteController(robot, rpc_port=0, monitor_port=0).start()
    yield ctrl
    ctrl.close()
    robot.close()


def elite_driver(ctrl):
    from payload_agent.drivers.base import MotionLimits
    from payload_agent.drivers.elite_ec.driver import EliteECDriver

    opts = EliteECDriver.parse_options({"type": "elite_ec", "host": "127.0.0.1", "rpc_port": ctrl.rpc_port,
                                        "monitor_port": ctrl.monitor_port})
    return EliteECDriver(opts, MotionLimits(2.6, 6.0))


def test_elite_driver_reads_digital_inputs(elite):
    drv = elite_driver(elite)
    drv.connect()
    try:
        assert drv.read_digital_input(5) is False
        elite.set_digital_input(5, True)
        assert drv.read_digital_input(5) is True and drv.read_digital_input(4) is False
        assert ("getInput", {"addr": 5}) in elite.requests
        elite.set_mode(0)  # teach mode: reading an input still works
        assert drv.read_digital_input(5) is True
        with pytest.raises(CommunicationError, match="X64.*X0..X63"):
            drv.read_digital_input(64)
        with pytest.raises(ValueError, match="non-negative integer"):
            drv.read_digital_input(-1)
        elite.set_garbage_reply("getInput", '{"jsonrpc":"2.0","result":"7","id":null}')
        with pytest.raises(CommunicationError, match="returned 7, expected 0 or 1"):
            drv.read_digital_input(5)
    finally:
        drv.close()
    with pytest.raises(ValueError, match=r"\[0, 63\]"):
        elite.set_digital_input(64, 1)


def test_watch_with_elite_fake_input(elite, base_cfg):
    runs = []

    def pulse():  # the edge comes after the watch has read the input low (a loaded machine connects slowly)
        deadline = time.monotonic() + 30
        while ("getInput", {"addr": 3}) not in elite.requests and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)
        elite.set_digital_input(3, 1)

    def run_once():
        runs.append(elite.requests.count(("getInput", {"addr": 3})))
        return 0

    threading.Thread(target=pulse, daemon=True).start()
    give_up = threading.Event()
    timer = threading.Timer(60, give_up.set)  # never hang the suite
    timer.start()
    try:
        code = watch(input_cfg(base_cfg), run_once, driver_factory=lambda: elite_driver(elite), out=Log(), max_runs=1,
                     stop_event=give_up)
    finally:
        timer.cancel()
    assert code == 0 and len(runs) == 1 and runs[0] >= 2  # it read low at least once before the edge
