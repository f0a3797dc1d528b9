"""The jobs a cell's PLC starts (Identify, Verify, Apply), one at a time per robot, with the PLCopen handshake.

Protocol-free: the OPC UA and Modbus servers only map these to their nodes and registers.

Handshake per command (PLCopen function-block convention, what PLC programmers know):

- a rising edge of ``Execute`` (or an OPC UA method call) starts the job; ``Busy`` is true while it runs;
- it ends with ``Done`` (success) or ``Error`` with ``ErrorID``; both stay set until ``Execute`` falls
  (a method call's outputs stay until the next start);
- a start while any job of this robot runs is refused: ``Error`` with ``ErrorID`` = ``ERROR_BUSY``,
  nothing is started (the running job is left alone).

``ErrorID`` is the command line's exit code (``errors.py``; 7 = verify found another tool), or
``ERROR_BUSY`` / ``ERROR_BAD_REQUEST``. Jobs are ordinary unattended sessions: the robot's session lock,
the safety gate, stop and keep the data on faults.

Commands:
- ``Identify(tool)``: a full identification, written to the controller when its quality checks pass, and
  stored in the tool library under ``tool`` (when named);
- ``Verify(tool)``: seconds of motion testing the mounted tool against the library's ``tool`` (empty:
  the controller's current setting); nothing written;
- ``Apply(tool)``: writes the library's payload of ``tool`` to the controller and reads it back; no motion.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Callable

from payload_agent.configuration.config import Config
from payload_agent.errors import PayloadAgentError, ToolMismatchError

COMMANDS = ("Identify", "Verify", "Apply")
ERROR_BUSY = 100  # another job of this robot is running: the start was refused
ERROR_BAD_REQUEST = 101  # the request itself is unusable (unknown command, bad tool name)


@dataclass
class Handshake:
    """One command's outputs (what the PLC reads)."""

    busy: bool = False
    done: bool = False
    error: bool = False
    error_id: int = 0
    message: str = ""


@dataclass
class LastResult:
    command: str = ""
    tool: str = ""
    verdict: str = ""  # match | mismatch | identified | applied | failed
    mass_kg: float = float("nan")
    cog_mm: tuple[float, float, float] = (float("nan"),) * 3
    mass_std_kg: float = float("nan")
    cog_std_mm: tuple[float, float, float] = (float("nan"),) * 3
    run_dir: str = ""
    time_utc: str = ""
    message: str = ""


@dataclass
class FlangeLoad:
    """The payload this agent last wrote to or verified on the controller (OPC 40010 LoadType's content)."""

    mass_kg: float = float("nan")
    cog_mm: tuple[float, float, float] = (float("nan"),) * 3
    inertia_kgm2: tuple[float, float, float] | None = None  # principal moments, when identified
    tool: str = ""
    orientation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # A, B, C of the principal axes (z-y'-x'')


def flange_load(mass_kg: float, cog_mm, tensor_kgm2, tool: str) -> FlangeLoad:
    """The LoadType content of a payload: the inertia tensor about the CoM (flange axes; None: unknown) as
    principal moments with the orientation of their axes (``output.payload_forms``, the KUKA / OPC 40010 form)."""
    cog = tuple(float(c) for c in cog_mm)
    if tensor_kgm2 is None:
        return FlangeLoad(float(mass_kg), cog, None, tool)  # type: ignore[arg-type]
    from payload_agent.output.payload_forms import payload_forms

    p = payload_forms(float(mass_kg), [c / 1000.0 for c in cog], tensor_kgm2)["principal"]
    abc = tuple(round(float(v), 9) for v in p["abc_deg"])  # not 30.00000000000001
    return FlangeLoad(float(mass_kg), cog, tuple(p["j_kgm2"]), tool, abc)  # type: ignore[arg-type]


@dataclass
class RobotJobs:
    """One robot's job runner and everything the servers show of it."""

    config: Config
    cell: Any = None  # a running SimulatedCell for a simulated robot (shared by every job)
    log: Callable[[str], None] = lambda text: None
    handshakes: dict[str, Handshake] = field(default_factory=lambda: {c: Handshake() for c in COMMANDS})
    last: LastResult = field(default_factory=LastResult)
    load: FlangeLoad = field(default_factory=FlangeLoad)
    state: str = "idle"  # idle | busy: <command> | the last error
    changed: threading.Event = field(default_factory=threading.Event)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _thread: threading.Thread | None = None
    _number: int | None = None

    inline: bool = False  # jobs run on the thread that calls ``run_pending`` (serve's main thread: signals stop them)
    _pending: tuple[str, str] | None = None
    _wake: threading.Event = field(default_factory=threading.Event)

    @property
    def busy(self) -> bool:
        return self._pending is not None or (self._thread is not None and self._thread.is_alive())

    def run_pending(self, timeout_s: float) -> None:
        """``inline`` mode: run the started job here, if there is one (waits up to ``timeout_s`` for one)."""
        if self._wake.wait(timeout_s):
            self._wake.clear()
            job = self._pending
            if job is not None:
                try:
                    self._run(*job)
                finally:
                    self._pending = None
                    self.changed.set()

    def start(self, command: str, tool: str, number: int | None = None) -> tuple[bool, int, str]:
        """Start ``command``; (started, error id, message). Refused while another job runs. ``number``: the
        tool number to give a tool that Identify adds to the library (a PLC names tools by number)."""
        if command not in COMMANDS:
            return False, ERROR_BAD_REQUEST, f"unknown command {command!r} ({', '.join(COMMANDS)})"
        with self._lock:
            hs = self.handshakes[command]
            if self.busy:
                running = self.state
                hs.busy, hs.done, hs.error, hs.error_id = False, False, True, ERROR_BUSY
                hs.message = f"refused: the robot is {running}; nothing was started"
                self.changed.set()
                return False, ERROR_BUSY, hs.message
            hs.busy, hs.done, hs.error, hs.error_id, hs.message = True, False, False, 0, ""
            self.state = f"busy: {command}"
            self._number = number
            if self.inline:
                self._pending = (command, tool.strip())
                self._wake.set()
            else:
                self._thread = threading.Thread(target=self._run, args=(command, tool.strip()), daemon=True,
                                                name=f"plc-{command}-{self.config.robot.name}")
                self._thread.start()
            self.changed.set()
            return True, 0, "started"

    def reset(self, command: str) -> None:
        """``Execute`` fell: clear Done/Error (a running job keeps Busy)."""
        with self._lock:
            hs = self.handshakes[command]
            if not hs.busy:
                hs.done = hs.error = False
                hs.error_id = 0
                self.changed.set()

    def wait(self, timeout_s: float | None = None) -> None:
        t = self._thread
        if t is not None:
            t.join(timeout_s)

    def _run(self, command: str, tool: str) -> None:
        hs = self.handshakes[command]
        code, message = 0, "done"
        try:
            {"Identify": self._identify, "Verify": self._verify, "Apply": self._apply}[command](tool or None)
        except ToolMismatchError as exc:
            code, message = exc.exit_code, str(exc)
            outcome = getattr(exc, "outcome", None)
            if outcome is not None:
                self._record_verify(command, outcome, "mismatch")
        except PayloadAgentError as exc:
            code, message = exc.exit_code, str(exc)
        except KeyboardInterrupt:  # SIGTERM / Ctrl-C on serve's main thread: the session stopped the robot
            with self._lock:
                hs.busy, hs.error, hs.error_id = False, True, 4
                hs.message = "interrupted (serve is stopping): the robot was stopped, recorded data kept"
                self.state = "stopped"
                self.changed.set()
            raise
        except BaseException as exc:  # a bug: reported as such, never a dead server
            code, message = 1, f"unexpected error: {type(exc).__name__}: {exc}"
        self.log(f"{command}({tool!r}): " + ("done" if code == 0 else f"error {code}: {message}"))
        with self._lock:
            hs.busy, hs.done, hs.error, hs.error_id, hs.message = False, code == 0, code != 0, code, message
            if code != 0 and not (code == ToolMismatchError.exit_code and self.last.command == command):
                self.last = LastResult(command, tool, "failed", time_utc=_now(), message=message)
            self.state = "idle" if code == 0 else f"idle (last {command} failed: error {code})"
            self.changed.set()

    # -- the jobs ----------------------------------------------------------------------------
    def _identify(self, tool: str | None) -> None:
        from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

        outcome = run_identification(self.config, RunOptions(unattended=True, apply=True, tool=tool),
                                                  OperatorUI(out=self.log, progress=False),
                                                  SimulatedCellUse(cell=self.cell))
        est = outcome.result.primary
        cog_std = tuple(1000 * s for s in est.cog_std_m) if est.cog_std_m is not None else (float("nan"),) * 3
        self.last = LastResult("Identify", tool or "", "identified", float(est.mass_kg),
                               tuple(float(c) for c in est.cog_mm), float(est.mass_std_kg or float("nan")),
                               cog_std, str(outcome.run_dir), _now())  # type: ignore[arg-type]
        if tool and self._number:
            from dataclasses import replace

            from payload_agent.recording.state import RobotState
            from payload_agent.tools import library

            db = library.tool_library_path(RobotState.for_config(self.config).root)
            entry = library.get(db, self.config.robot.name, tool)
            if entry is not None and entry.number is None:
                library.store(db, self.config.robot.name, replace(entry, number=self._number, time_utc=""))
        if outcome.applied is not None:
            tensor = outcome.result.extra.get("inertia_com_kgm2")  # the identified one, None when refused
            self.load = flange_load(outcome.applied.mass_kg, [1000 * c for c in outcome.applied.cog_m], tensor,
                                    tool or "")

    def _verify(self, tool: str | None) -> None:
        from payload_agent.session.verify import VerifyOptions, verify_tool

        outcome = verify_tool(self.config, VerifyOptions(tool=tool, unattended=True, cell=self.cell, out=self.log))
        self._record_verify("Verify", outcome, "match")

    def _record_verify(self, command: str, outcome, verdict: str) -> None:
        r = outcome.result
        self.last = LastResult(command, outcome.expected.name, verdict, r.mass_kg, r.cog_mm, r.mass_std_kg,
                               r.cog_std_mm, str(outcome.run_dir), _now(), r.describe(outcome.expected.name))
        if verdict == "match" and outcome.setting_matches:
            e = outcome.expected
            self.load = flange_load(e.mass_kg, e.cog_mm, e.inertia_tensor(), e.name)

    def _apply(self, tool: str | None) -> None:
        from payload_agent.recording.state import RobotState
        from payload_agent.session.connection import build_driver
        from payload_agent.session.robot_lock import robot_lock
        from payload_agent.session.verify import write_and_check
        from payload_agent.tools import library

        if tool is None:
            raise PayloadAgentError("Apply needs a tool name (the library entry to write)")
        state = RobotState.for_config(self.config)
        entry = library.require(library.tool_library_path(state.root), self.config.robot.name, tool)
        with robot_lock(state, "serve Apply", self.config.robot.name, self.log):
            driver = build_driver(self.config, self.cell.options if self.cell is not None else None)
            try:
                driver.connect()
                back = write_and_check(driver, entry, self.log)
            finally:
                driver.close()
        self.last = LastResult("Apply", tool, "applied", back.mass_kg, tuple(1000 * c for c in back.cog_m),
                               entry.mass_std_kg or float("nan"), entry.cog_std_mm or (float("nan"),) * 3, "",
                               _now())  # type: ignore[arg-type]
        self.load = flange_load(back.mass_kg, [1000 * c for c in back.cog_m], entry.inertia_tensor(), tool)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")
