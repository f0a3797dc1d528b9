"""What the operator sees and what the run log keeps: verbosity (-v/-q), JSON mode, the log file.

One ``Console`` per command. Human text goes to stdout, or to stderr with ``--json`` (stdout
then carries exactly one JSON document, for cell software). Levels:

- ``say``: the normal narrative (connected, plan, gate verdict, result table); hidden by -q;
- ``detail``: per-move lines and other chatter; shown only with -v;
- ``warn``: always shown;
- ``result``: the final summary; shown even with -q.

Everything said is also logged (logger ``payload_agent.console``), and ``attach_run_log``
adds ``RUN_DIR/run.log``: every line of the session at DEBUG, from the first line of the
command (lines said before the run folder existed are kept in a backlog and written first).
The backlog starts empty with each ``Console`` (a command) and again when a run log ends, so in
one process (``watch``, the tests, an embedding program) no run log holds an earlier command's
or an earlier run's lines, whether that one ended well or in an exception.

``ask`` asks on the terminal; with stdin closed or at end of input it raises NoTerminalError
naming the flag that answers the question instead, so nothing ever moves unasked.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import sys
from pathlib import Path
from typing import Any, Callable, TextIO

from payload_agent.errors import NoTerminalError
from payload_agent.output.line_input import read_line

LOGGER = "payload_agent"
CONSOLE_LOGGER = "payload_agent.console"
RUN_LOG_NAME = "run.log"
BACKLOG_LINES = 5000
_FORMAT = "%(asctime)s.%(msecs)03d %(levelname)-7s %(name)s: %(message)s"
_DATEFMT = "%Y-%m-%d %H:%M:%S"


class _Backlog(logging.Handler):
    """Keeps the last records so that a run log can start with what was said before the folder existed."""

    def __init__(self, capacity: int = BACKLOG_LINES):
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []
        self.capacity = capacity

    def emit(self, record: logging.LogRecord) -> None:  # called under the handler's lock
        self.records.append(record)
        if len(self.records) > self.capacity:
            del self.records[: len(self.records) - self.capacity]

    def clear(self) -> None:
        with self.lock:
            self.records = []


class _NotConsole(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not record.name.startswith(CONSOLE_LOGGER)


_backlog = _Backlog()
_stream_handler: logging.Handler | None = None


def setup_logging(verbosity: int = 0, stream: TextIO | None = None) -> None:
    """Library log records to the terminal (stderr): warnings, or everything with -v. Idempotent."""
    global _stream_handler
    root = _keep_backlog()
    if _stream_handler is not None:
        root.removeHandler(_stream_handler)
    _stream_handler = logging.StreamHandler(stream or sys.stderr)
    _stream_handler.setLevel(logging.DEBUG if verbosity > 0 else logging.WARNING)
    _stream_handler.addFilter(_NotConsole())  # the console prints its own lines
    _stream_handler.setFormatter(logging.Formatter("payload-agent: %(levelname)s: %(message)s"))
    root.addHandler(_stream_handler)


def attach_run_log(run_dir: Path) -> logging.Handler:
    """Start ``RUN_DIR/run.log`` (DEBUG, with the backlog of this command so far); returns the handler.

    Call ``detach_run_log`` when the session ends (the runner does both; any caller may).
    """
    root = _keep_backlog()
    handler = logging.FileHandler(Path(run_dir) / RUN_LOG_NAME, encoding="utf-8")
    handler.setLevel(logging.DEBUG)
    handler.setFormatter(logging.Formatter(_FORMAT, _DATEFMT))
    with _backlog.lock:  # the early lines go to this log once (another run of the command must not repeat
        for record in _backlog.records:  # them), and nothing said meanwhile is lost or out of order
            handler.handle(record)
        _backlog.records = []
        root.addHandler(handler)
    return handler


def detach_run_log(handler: logging.Handler | None) -> None:
    """End a run log (also after a failed run): the next run's log starts with what is said after this."""
    if handler is None:
        return
    logging.getLogger(LOGGER).removeHandler(handler)
    _backlog.clear()
    try:
        handler.close()
    except Exception:
        pass


def begin_command_log() -> None:
    """A new command (a ``Console``): its run log starts here, not with an earlier command of this process
    (tests, an embedding program); from here on everything said is kept for it at DEBUG."""
    _keep_backlog()
    _backlog.clear()


def _keep_backlog() -> logging.Logger:
    root = logging.getLogger(LOGGER)
    root.setLevel(logging.DEBUG)
    if _backlog not in root.handlers:
        root.addHandler(_backlog)
    return root


class Console:
    """The command's output channel; see the module docstring for the levels."""

    def __init__(self, verbosity: int = 0, json_mode: bool = False, *, stdout: TextIO | None = None,
                 stderr: TextIO | None = None, stdin: TextIO | None = None):
        self.verbosity = verbosity
        self.json_mode = json_mode
        self.stdout = stdout or sys.stdout
        self.stderr = stderr or sys.stderr
        self.stdin = stdin or sys.stdin
        self.log = logging.getLogger(CONSOLE_LOGGER)
        begin_command_log()  # one Console per command: the run log keeps its every line, and no earlier command's

    @property
    def human(self) -> TextIO:
        """Where human-readable text goes (also the live progress line)."""
        return self.stderr if self.json_mode else self.stdout

    def _print(self, text: str, stream: TextIO | None = None) -> None:
        stream = stream or self.human
        try:
            stream.write(text + "\n")
            stream.flush()
        except (OSError, ValueError):
            pass  # a closed terminal must not end a session that moves a robot

    def say(self, text: str) -> None:
        self.log.info(text)
        if self.verbosity >= 0:
            self._print(text)

    def detail(self, text: str) -> None:
        self.log.debug(text)
        if self.verbosity > 0:
            self._print(text)

    def warn(self, text: str) -> None:
        self.log.warning(text)
        self._print(text)

    def result(self, text: str) -> None:
        self.log.info(text)
        self._print(text)

    def error(self, text: str) -> None:
        self.log.error(text)
        self._print(text, self.stderr)

    def emit_json(self, data: Any) -> None:
        """The command's one JSON document on stdout (only in --json mode)."""
        if not self.json_mode:
            return
        self._print(json.dumps(to_jsonable(data), indent=2, allow_nan=False), self.stdout)

    def asker(self, answer_flag: str) -> Callable[[str], str]:
        """An ``ask(prompt)`` for the runner; ``answer_flag`` names what to pass when nobody can answer."""

        def ask(prompt: str) -> str:
            self.log.info(prompt.strip())
            if self.stdin is None or self.stdin.closed:
                raise NoTerminalError(_no_terminal(prompt, answer_flag))
            try:
                self.human.write(prompt)
                self.human.flush()
                line = read_line(self.stdin)
            except (OSError, ValueError, EOFError):
                raise NoTerminalError(_no_terminal(prompt, answer_flag)) from None
            if line == "":  # end of input: stdin closed or </dev/null
                raise NoTerminalError(_no_terminal(prompt, answer_flag))
            self.log.info("answer: %s", line.strip())
            return line.rstrip("\n")

        return ask


def _no_terminal(prompt: str, answer_flag: str) -> str:
    question = prompt.strip().split("\n")[-1]
    return (f"no terminal to ask {question!r} (standard input is closed or at its end); nothing moved. "
            f"{answer_flag}")


def to_jsonable(value: Any) -> Any:
    """Dataclasses, paths, tuples and numpy values -> plain JSON; NaN and infinity -> null."""
    if callable(getattr(value, "to_json", None)) and not isinstance(value, type):
        return to_jsonable(value.to_json())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return to_jsonable(value.tolist())
    return str(value)
