"""`payload-agent watch`: wait for a trigger, then run one unattended identification; repeat.

Triggers (the robot YAML's ``watch`` section, ``configuration.watch.WatchConfig``):

- ``file``: a file appears at ``watch.trigger.path``. It is deleted just before the run
  starts, so one file is one run. A file created while a run is in progress is seen after
  that run and starts exactly one more run (triggers during a run are *coalesced* into one).
- ``digital_input``: the controller's digital input ``watch.trigger.index`` goes from low to
  high (a rising edge), read with ``driver.read_digital_input`` on a connection of its own.
  An input that is already high when watching starts, or that is still high after a run,
  must go low first. Edges during a run are *ignored*: the connection is closed while the
  run has the robot, and the level read afterwards is the new reference. Connection errors
  are logged and retried every poll; a watcher survives a controller reboot.

Only one run at a time: ``run_once`` is called on the calling thread and the trigger is not
polled while it runs. A run that fails (non-zero exit code) is logged and watching goes on.

Stopping (safety first):

- ``stop_event`` set, SIGTERM or SIGINT while waiting: the loop ends cleanly, exit code 0;
- SIGTERM or SIGINT during a run: the handler raises KeyboardInterrupt in the main thread,
  which is the runner's Ctrl-C path: the robot is stopped, the recorded data is kept, the
  run returns (or raises) and the loop ends. Only the *first* signal is turned into an
  exception; later ones are logged and otherwise ignored, so a second SIGTERM can never
  interrupt the runner while it is stopping the robot.

Signal handlers are installed only when ``watch`` runs on the main thread (Python delivers
signals there) and are restored when it returns.

Exit code: 0 when stopped between runs; with ``max_runs``, the last run's exit code once that
many runs have been made; when a run was interrupted by a signal, that run's exit code
(130 for SIGINT, 143 for SIGTERM if the interrupt escaped ``run_once``).
"""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Callable

from payload_agent.configuration.config import Config
from payload_agent.configuration.watch import WatchConfig
from payload_agent.drivers.base import Driver
from payload_agent.errors import ConfigError, PayloadAgentError, UnsupportedCapability
from payload_agent.tools.library import NAME_PATTERN

EXIT_MEANING = {0: "success", 1: "unexpected error", 2: "configuration/plan/safety refusal", 3: "robot not ready",
                4: "motion aborted", 5: "data or quality failure", 6: "communication failure",
                130: "interrupted (SIGINT)", 143: "terminated (SIGTERM)"}
MAX_RECONNECT_WAIT_S = 10.0


# how often a wait between polls looks for a signal (the handler takes no lock, so it cannot wake the wait)
SIGNAL_CHECK_S = 0.1


@dataclass
class _State:
    """``stop``: the caller's stop request (another thread sets it). ``signalled``: set by the signal handler,
    which must take no lock: ``Event.set()`` there waits for the event's own lock, which the main thread may hold
    inside ``stop.wait()`` when the signal arrives, and then waits for ever (a watch under test once ignored
    SIGTERM for 30 s this way; CPython gh-126434 is the same deadlock with multiprocessing.Event)."""

    stop: threading.Event
    in_run: bool = False
    interrupted_by: int | None = None  # signal number that interrupted a run
    signals: list[int] = field(default_factory=list)
    signalled: bool = False

    def stopped(self) -> bool:
        return self.signalled or self.stop.is_set()

    def wait(self, seconds: float) -> None:
        """Up to ``seconds``, ending early once stopped."""
        deadline = time.monotonic() + seconds
        while not self.stopped():
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.stop.wait(min(left, SIGNAL_CHECK_S))


def _stamp() -> str:
    return datetime.now().astimezone().isoformat(timespec="seconds")


def watch(config: Config, run_once: Callable[[], int], *, driver_factory: Callable[[], Driver] | None = None,
          stop_event: threading.Event | None = None, out: Callable[[str], None] = print,
          max_runs: int | None = None, run_tool: Callable[[str | None], int] | None = None) -> int:
    """Wait for ``config.watch``'s trigger, call ``run_once()`` (an unattended run, returning its
    exit code), repeat until stopped or ``max_runs`` runs were made; returns an exit code.

    ``driver_factory()`` returns a new, not yet connected driver for this robot; it is needed
    for the ``digital_input`` trigger only (``watch`` connects and closes it).
    Raises ConfigError when the config has no usable ``watch`` section, UnsupportedCapability
    when the driver cannot read digital inputs.

    ``run_tool(name)``, when given, is called instead of ``run_once`` with the tool the trigger names
    (a file trigger: the file's first line, a library name or tool number; a register trigger with
    ``tool_from_value``: its value; a digital input with ``tool_inputs``: their binary number; None when
    the trigger names none): ``session.tool_change.change_tool`` verifies a known tool and identifies only a new one.
    """
    wc = config.watch
    if wc is None:
        raise ConfigError("watch", "the robot YAML has no watch section: add watch.trigger "
                                   "(type: file + path, or type: digital_input + index)", config.source)
    if wc.trigger == "file":
        if wc.path is None:
            raise ConfigError("watch.trigger.path", "a file trigger needs a path", config.source)
        trigger: _Trigger = _FileTrigger(Path(wc.path), out)
    elif wc.trigger == "register":
        if driver_factory is None:
            raise ConfigError("watch.trigger", "a register trigger needs a driver connection (driver_factory)",
                              config.source)
        trigger = _InputTrigger(wc, driver_factory, out)
    elif wc.trigger == "digital_input":
        if wc.input_index is None:
            raise ConfigError("watch.trigger.index", "a digital_input trigger needs an input index", config.source)
        if driver_factory is None:
            raise ConfigError("watch.trigger", "a digital_input trigger needs a driver connection "
                                               "(driver_factory)", config.source)
        trigger = _InputTrigger(wc, driver_factory, out)
    else:
        raise ConfigError("watch.trigger.type", f"unknown trigger {wc.trigger!r} (file or digital_input)",
                          config.source)

    state = _State(stop_event if stop_event is not None else threading.Event())
    restore = _install_signal_handlers(state, out)
    runs = 0
    last_code = 0
    try:
        out(f"{_stamp()} watch: waiting for {trigger.describe()} (poll every {wc.poll_interval_s:g} s)"
            + (f", at most {max_runs} run(s)" if max_runs is not None else ""))
        while not state.stopped():
            if max_runs is not None and runs >= max_runs:
                break
            fired = trigger.poll()
            if not fired:
                state.wait(trigger.wait_s(wc.poll_interval_s))
                continue
            if state.stopped():
                break
            trigger.before_run()
            runs += 1
            out(f"{_stamp()} watch: trigger: {fired}; starting run {runs}")
            state.in_run = True
            try:
                last_code = int(run_once() if run_tool is None else run_tool(trigger.tool))
            except KeyboardInterrupt:
                last_code = 143 if state.interrupted_by == signal.SIGTERM else 130
                out(f"{_stamp()} watch: run {runs} interrupted; the runner stopped the robot and kept the data")
            except PayloadAgentError as exc:
                last_code = exc.exit_code
                out(f"{_stamp()} watch: run {runs} failed: {exc}")
            finally:
                state.in_run = False
            out(f"{_stamp()} watch: run {runs} finished: exit code {last_code} "
                f"({EXIT_MEANING.get(last_code, 'unknown')})")
            if state.interrupted_by is not None:
                break
            trigger.after_run()
        if state.stopped():
            reason = (f"signal {signal.Signals(state.signals[0]).name}" if state.signals else "stop requested")
            out(f"{_stamp()} watch: stopped ({reason}) after {runs} run(s)")
            return last_code if state.interrupted_by is not None else 0
        out(f"{_stamp()} watch: {runs} run(s) made, as asked; stopping")
        return last_code
    finally:
        trigger.close()
        restore()


# -- signals ----------------------------------------------------------------------------------
def _install_signal_handlers(state: _State, out: Callable[[str], None]) -> Callable[[], None]:
    if threading.current_thread() is not threading.main_thread():
        return lambda: None  # signals are delivered to the main thread only; the caller uses stop_event

    def handler(signum, frame):
        state.signals.append(signum)
        first = not state.stopped()
        state.signalled = True  # no state.stop.set() here: see _State
        if state.in_run and first:
            state.interrupted_by = signum
            # the runner's Ctrl-C path: stop the robot, keep the data
            raise KeyboardInterrupt(f"signal {signal.Signals(signum).name} during a run")
        if state.in_run:
            try:
                out(f"{_stamp()} watch: {signal.Signals(signum).name} again; the run is already stopping")
            except Exception:
                pass

    previous = {}
    for sig in (signal.SIGTERM, signal.SIGINT):
        previous[sig] = signal.getsignal(sig)
        signal.signal(sig, handler)

    def restore() -> None:
        for sig, h in previous.items():
            signal.signal(sig, h if h is not None else signal.SIG_DFL)

    return restore


# -- triggers ---------------------------------------------------------------------------------
class _Trigger:
    tool: str | None = None  # the tool the last trigger named, if it names one

    def describe(self) -> str:
        raise NotImplementedError

    def poll(self) -> str | None:
        """A sentence describing the trigger if it fired, else None."""
        raise NotImplementedError

    def wait_s(self, poll_interval_s: float) -> float:
        return poll_interval_s

    def before_run(self) -> None:
        pass

    def after_run(self) -> None:
        pass

    def close(self) -> None:
        pass


class _FileTrigger(_Trigger):
    def __init__(self, path: Path, out: Callable[[str], None]):
        self.path = path
        self.out = out
        self._seen: str | None = None

    def describe(self) -> str:
        return f"file {self.path}"

    def poll(self) -> str | None:
        if not self.path.exists():
            return None
        try:
            note = self.path.read_text(encoding="utf-8", errors="replace").strip()[:200]
        except OSError:
            note = ""
        first = note.splitlines()[0].strip() if note else ""
        self.tool = first if NAME_PATTERN.match(first) else None  # a first line that is a tool name (or number)
        return f"file {self.path} appeared" + (f" ({note!r})" if note else "")

    def before_run(self) -> None:
        # consume the file: one file = one run. If it cannot be removed, every poll would start
        # another run, so this is fatal.
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise ConfigError("watch.trigger.path", f"cannot remove the trigger file {self.path} ({exc}); "
                                                    "watch needs write access to its folder") from None


class _InputTrigger(_Trigger):
    """A digital input's rising edge, or the trigger register going from 0 to non-zero.

    With ``tool_inputs`` the tool number is read from those inputs (binary, least significant bit first)
    right after the edge: the PLC or tool changer sets them before it raises the trigger. With
    ``tool_from_value`` the register's value is the tool number, and a change from one non-zero value to
    another is a tool change too (a PLC that writes the next tool's number without clearing first)."""

    def __init__(self, wc: WatchConfig, factory: Callable[[], Driver], out: Callable[[str], None]):
        self.index = None if wc.trigger == "register" else int(wc.input_index)  # type: ignore[arg-type]
        self.tool_inputs = wc.tool_inputs
        self.from_value = wc.tool_from_value
        self.factory = factory
        self.out = out
        self.driver: Driver | None = None
        self.previous: int | None = None  # None: no reference level yet (start, after a run or an error)
        self.failures = 0

    def _what(self) -> str:
        return "the trigger register" if self.index is None else f"digital input {self.index}"

    def describe(self) -> str:
        if self.index is None:
            return ("a new non-zero tool number in the controller's trigger register" if self.from_value
                    else "a rising edge on the controller's trigger register")
        coded = (f" (tool number on inputs {', '.join(map(str, self.tool_inputs))}, least significant first)"
                 if self.tool_inputs else "")
        return f"a rising edge on the controller's digital input {self.index}{coded}"

    def wait_s(self, poll_interval_s: float) -> float:
        # back off while the controller cannot be reached, up to MAX_RECONNECT_WAIT_S
        return poll_interval_s if not self.failures else min(MAX_RECONNECT_WAIT_S,
                                                             poll_interval_s * 2 ** min(self.failures, 6))

    def _level(self, driver: Driver) -> int:
        if self.index is None:
            value = int(driver.read_trigger())
            return value if self.from_value else int(value != 0)
        return int(bool(driver.read_digital_input(self.index)))

    def _tool_number(self, driver: Driver) -> int:
        return sum(int(bool(driver.read_digital_input(i))) << bit for bit, i in enumerate(self.tool_inputs))

    def poll(self) -> str | None:
        try:
            if self.driver is None:
                self.driver = self.factory()
                self.driver.connect()
            level = self._level(self.driver)
            previous = self.previous
            fired = previous is not None and level != 0 and level != previous
            number = self._tool_number(self.driver) if fired and self.tool_inputs else None
        except UnsupportedCapability:
            self.close()
            raise
        except PayloadAgentError as exc:
            self.failures += 1
            if self.failures == 1 or self.failures % 10 == 0:
                self.out(f"{_stamp()} watch: cannot read {self._what()}: {exc} (retrying)")
            self.close()
            self.previous = None
            return None
        if self.failures:
            self.out(f"{_stamp()} watch: {self._what()} readable again")
            self.failures = 0
        self.previous = level
        if not fired:
            return None
        if self.from_value:
            number = level
        self.tool = str(number) if number else None
        if self.index is None and self.from_value:
            return f"the trigger register reads tool number {level}"
        named = "" if number is None else f"; tool number {number}" if number else "; no tool number (inputs all low)"
        return f"{self._what()} went high{named}"

    def before_run(self) -> None:
        self.close()  # the run makes its own connection; nothing else talks to the robot meanwhile

    def after_run(self) -> None:
        self.previous = None  # the level after the run is the new reference: edges during it are ignored

    def close(self) -> None:
        d, self.driver = self.driver, None
        if d is not None:
            try:
                d.close()
            except Exception:
                pass
