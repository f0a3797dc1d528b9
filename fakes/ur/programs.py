"""The simulated controller's script ports (30001-30003) and the one program that runs.

A full program received on a script port replaces the running one (as on the real
controller); a ``sec`` program runs inline without disturbing it. When a program ends for
any reason (finished, stopped from the dashboard, by a safety stop, by a new program) a move
it started is brought to a stop: the arm never runs on without the program that commanded it.
"""

from __future__ import annotations

import socket
import threading
from typing import TYPE_CHECKING

from payload_agent.fakes.ur.constants import (ROBOT_MODE_NAMES, ROBOT_MODE_RUNNING, RUNTIME_PLAYING,
                                              RUNTIME_STOPPED, SAFETY_MODE_NAMES)
from payload_agent.fakes.ur.control_script import compile_program
from payload_agent.fakes.ur.urscript import (Program, ProgramError, ProgramStopped, ScriptCollector,
                                             ScriptCompileError, ScriptProgram)

if TYPE_CHECKING:
    from payload_agent.fakes.ur.controller import URControllerCore


class ProgramHost:
    """Receives scripts, starts and stops the controller's program."""

    def __init__(self, ctrl: "URControllerCore"):
        self.ctrl = ctrl
        self.program: Program | None = None
        self.program_name = ""
        self.programs_run: list[str] = []  # names of programs started
        self.last_script = ""  # the last full program received on a script port
        self._lock = threading.Lock()

    def serve_script(self, conn: socket.socket) -> None:
        c = self.ctrl
        port = conn.getsockname()[1]
        collector = ScriptCollector()
        while not c.closing.is_set():
            data = conn.recv(65536)
            if not data:
                return
            for kind, text in collector.feed(data.decode(errors="replace")):
                c.note(f"script port {port}: received {kind} ({len(text)} chars)")
                if not c.remote_control:  # PolyScope 5 in Local mode ignores programs from the network
                    self.script_error(f"port {port}: program ignored, the robot is not in remote control")
                    continue
                if kind == "sec":
                    self._run_secondary(text, port)
                else:
                    self.run_script(text, source=f"port {port}")

    def _run_secondary(self, text: str, port: int) -> None:
        try:
            program = compile_program(self.ctrl, text, secondary=True)
            if not isinstance(program, ScriptProgram):
                raise ScriptCompileError("not a plain program")
            program.run_inline()
        except (ScriptCompileError, ProgramError) as exc:
            self.script_error(f"port {port} secondary program: {exc}")

    def run_script(self, text: str, source: str = "script") -> None:
        """Compile and start a URScript program (what the script ports do with a full program)."""
        self.last_script = text
        try:
            program = compile_program(self.ctrl, text)
        except ScriptCompileError as exc:
            self.script_error(f"{source}: {exc}")
            return
        self._start(program)

    def script_error(self, text: str) -> None:
        self.ctrl.script_errors.append(text)
        self.ctrl.note(f"script error: {text}")

    def _start(self, program: Program) -> None:
        c = self.ctrl
        with self._lock:
            self.stop_program("replaced by a new program", wait=True)
            st = c.robot.snapshot()
            with c.lock:
                if st.estop or st.protective_stop or c.robot_mode != ROBOT_MODE_RUNNING:
                    mode = SAFETY_MODE_NAMES[c.safety(st)[0]]
                    self.script_error(f"cannot start program {program.name!r}: robot mode "
                                      f"{ROBOT_MODE_NAMES.get(c.robot_mode)}, safety mode {mode}")
                    return
                c.runtime_state = RUNTIME_PLAYING
                self.program = program
                self.program_name = program.name
            self.programs_run.append(program.name)
            c.note(f"program {program.name!r} started")
            program.thread = threading.Thread(target=self._main, args=(program,), daemon=True,
                                              name=f"ur-fake-program-{program.name}")
            program.thread.start()

    def _main(self, program: Program) -> None:
        c = self.ctrl
        try:
            program.run()
            c.note(f"program {program.name!r} finished")
        except ProgramStopped as exc:
            c.note(f"program {program.name!r} stopped: {exc}")
        except ProgramError as exc:
            self.script_error(f"runtime error in {program.name!r}: {exc}")
        except Exception as exc:  # a bug in the fake: make it visible, never hang the client
            self.script_error(f"internal error in {program.name!r}: {exc!r}")
        finally:
            st = c.robot.snapshot()
            if st.moving and not (st.estop or st.protective_stop):  # the safety system is stopping it already
                c.robot.stop()  # a move of this program ends with it
            with c.lock:
                if self.program is program:
                    self.program = None
                    c.runtime_state = RUNTIME_STOPPED

    def stop_program(self, reason: str, wait: bool) -> bool:
        prog = self.program
        if prog is None:
            return False
        prog.stop(reason)
        if wait and prog.thread is not None and prog.thread is not threading.current_thread():
            prog.thread.join(timeout=2.0)
        return True
