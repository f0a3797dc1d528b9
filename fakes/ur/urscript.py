"""The simulated controller's URScript: splitting the script ports' byte stream into programs,
the program base (sync, sleep, movej, stopj on the simulated arm) and a small interpreter for
plain programs.

The subset: ``movej([...], a=, v=)``, ``stopj(a)``, ``set_payload(m, [x, y, z])`` and its
variants, ``set_tcp(p[...])``, ``textmsg(...)``, ``sleep(t)``, ``sync()``,
``write_output_integer_register`` / ``write_output_float_register``. Anything else is a compile
error, which the real controller reports too (for a name it does not know). ur_rtde's control
script is recognised and emulated separately (``control_script``).
"""

from __future__ import annotations

import ast
import math
import re
import threading
from typing import TYPE_CHECKING, Any, Sequence

from payload_agent.fakes.sim_robot import SimRefused

if TYPE_CHECKING:
    from payload_agent.fakes.ur.controller import URControllerCore

DEF_RE = re.compile(r"^(def|sec)\s+([A-Za-z_]\w*)\s*\(\s*\)\s*:\s*(#.*)?$")


def exact_time(st) -> float:
    """A simulation state's exact clock time (``t`` is the reported one, with timestamp jitter)."""
    return st.t_true if st.t_true is not None else st.t


class ProgramStopped(Exception):
    """The running program was stopped (dashboard stop, new program, safety stop, close)."""


class ProgramError(Exception):
    """A runtime error in the program: it ends, as on the real controller."""


class ScriptCompileError(Exception):
    """The uploaded URScript is not accepted (the fake's subset, or a syntax error)."""


class ScriptCollector:
    """Splits the byte stream of a script port into programs.

    A program starts with ``def name():`` or ``sec name():`` in column 0 and ends
    with ``end`` in column 0 (assumption: the real controller parses the script
    and needs no such layout rule; ur_rtde's control script and everything this
    project sends follow it). Any other line outside a program is a one-line
    program of its own, as the real controller treats a bare statement.
    """

    def __init__(self):
        self.buf = ""
        self.lines: list[str] | None = None
        self.kind = ""

    def feed(self, text: str) -> list[tuple[str, str]]:
        self.buf += text
        out = []
        while "\n" in self.buf:
            line, self.buf = self.buf.split("\n", 1)
            if self.lines is None:
                m = DEF_RE.match(line.rstrip())
                if m:
                    self.lines, self.kind = [line], m.group(1)
                elif line.strip() and not line.strip().startswith("#"):
                    out.append(("statement", f"def unnamed():\n  {line.strip()}\nend\n"))
            else:
                self.lines.append(line)
                if line.rstrip() == "end":
                    out.append((self.kind, "\n".join(self.lines) + "\n"))
                    self.lines = None
        return out


class Program:
    """A running URScript program: its thread, its stop flag and the motion primitives."""

    def __init__(self, ctrl: "URControllerCore", name: str):
        self.ctrl = ctrl
        self.name = name
        self.thread: threading.Thread | None = None
        self._stop_reason: str | None = None

    def stop(self, reason: str) -> None:
        if self._stop_reason is None:
            self._stop_reason = reason

    def check(self) -> None:
        if self._stop_reason is not None:
            raise ProgramStopped(self._stop_reason)
        if self.ctrl.closing.is_set():
            raise ProgramStopped("controller shut down")

    def sync(self) -> None:
        """Wait for the next control cycle (URScript sync())."""
        self.check()
        self.ctrl.wait_next_tick(lambda: self._stop_reason is not None)
        self.check()

    def sleep(self, seconds: float) -> None:
        end = self.ctrl.robot.now() + float(seconds)
        while self.ctrl.robot.now() < end - 1e-9:
            self.sync()

    def run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- motion primitives --------------------------------------------------------------------
    def wait_standstill(self, t_after: float) -> None:
        robot = self.ctrl.robot
        while True:
            st = robot.snapshot()
            if exact_time(st) > t_after and not st.moving:
                return
            self.sync()

    def start_movej(self, q: Sequence[float], a: float, v: float) -> float:
        q = [float(x) for x in q]
        if len(q) != 6 or not all(math.isfinite(x) for x in q):
            raise ProgramError(f"movej: target must be 6 finite joint values, got {q}")
        if any(abs(x) > 2 * math.pi + 1e-9 for x in q):
            raise ProgramError(f"movej: target {q} outside the joint limits (±360°)")
        if not (a > 0 and v > 0 and math.isfinite(a) and math.isfinite(v)):
            raise ProgramError(f"movej: a={a} and v={v} must be positive")
        self.ctrl.record_event("move", f"movej {[round(x, 6) for x in q]} a={a:g} v={v:g} ({self.name})")
        robot = self.ctrl.robot
        if robot.snapshot().moving:  # a new move first brings the running one to a stop
            robot.stop()
            self.wait_standstill(robot.now())
        try:
            robot.move_joints(q, v, a)
        except SimRefused as exc:
            raise ProgramError(f"movej refused: {exc}") from exc
        return robot.now()

    def movej(self, q: Sequence[float], a: float, v: float) -> None:
        t0 = self.start_movej(q, a, v)
        self.wait_standstill(t0)

    def start_stopj(self, a: float) -> float:
        if not (a > 0 and math.isfinite(a)):
            raise ProgramError(f"stopj: deceleration {a} must be positive")
        self.ctrl.record_event("stop", f"stopj a={a:g} ({self.name})")
        robot = self.ctrl.robot
        robot.stop(a)
        return robot.now()

    def stopj(self, a: float) -> None:
        self.wait_standstill(self.start_stopj(a))


def check_target_payload_inertia(inertia: Sequence[float]) -> None:
    """set_target_payload's inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (kg·m², about the CoG, flange axes) as the
    Script Manual bounds it: diagonal elements not negative, every element within ±133 kg·m²; else the
    script stops with a runtime error."""
    values = [float(v) for v in inertia]
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ProgramError(f"set_target_payload: inertia must be 6 finite numbers, got {list(inertia)}")
    if min(values[:3]) < 0:
        raise ProgramError(f"set_target_payload: inertia {values}: diagonal elements must not be negative")
    if max(abs(v) for v in values) > 133.0:
        raise ProgramError(f"set_target_payload: inertia {values}: elements must be within ±133 kg·m²")


# -- plain programs ---------------------------------------------------------------------------------

STATEMENT_FUNCS = {"movej", "stopj", "set_payload", "set_target_payload", "set_payload_mass", "set_payload_cog",
                   "set_tcp", "textmsg", "sleep", "sync", "write_output_integer_register",
                   "write_output_float_register"}
MOTION_FUNCS = {"movej", "stopj", "sleep", "sync"}


def _literal(node: ast.AST) -> Any:
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str, bool)):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _literal(node.operand)
        if not isinstance(v, (int, float)):
            raise ScriptCompileError("unary sign on a non-number")
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.List):
        return [_literal(e) for e in node.elts]
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Mult, ast.Div, ast.Add, ast.Sub)):
        a, b = _literal(node.left), _literal(node.right)
        if not all(isinstance(x, (int, float)) for x in (a, b)):
            raise ScriptCompileError("arithmetic on non-numbers")
        if isinstance(node.op, ast.Mult):
            return a * b
        if isinstance(node.op, ast.Add):
            return a + b
        if isinstance(node.op, ast.Sub):
            return a - b
        if b == 0:
            raise ScriptCompileError("division by zero")
        return a / b
    if isinstance(node, ast.Name) and node.id == "pi":
        return math.pi
    raise ScriptCompileError(f"unsupported expression {ast.dump(node)[:60]}")


class ScriptProgram(Program):
    """A plain program: a list of supported function calls, run in order."""

    def __init__(self, ctrl, name, calls: list[tuple[str, list, dict]]):
        super().__init__(ctrl, name)
        self.calls = calls

    def run(self) -> None:
        for fn, args, kw in self.calls:
            self.check()
            self._call(fn, args, kw)
            self.sync()

    def run_inline(self) -> None:
        for fn, args, kw in self.calls:
            self._call(fn, args, kw)

    def _call(self, fn: str, args: list, kw: dict) -> None:
        c = self.ctrl
        try:
            if fn == "movej":
                q = args[0] if args else kw["q"]
                a = float(kw.get("a", args[1] if len(args) > 1 else 1.4))
                v = float(kw.get("v", args[2] if len(args) > 2 else 1.05))
                self.movej(q, a, v)
            elif fn == "stopj":
                self.stopj(float(args[0] if args else kw["a"]))
            elif fn == "set_payload":
                m = float(args[0] if args else kw["m"])
                cog = args[1] if len(args) > 1 else kw.get("cog")
                c.set_payload_setting(m, cog)
            elif fn == "set_payload_mass":
                c.set_payload_setting(float(args[0]), None)
            elif fn == "set_payload_cog":
                c.set_payload_setting(c.payload_mass, args[0])
            elif fn == "set_target_payload":
                c.set_payload_setting(float(args[0]), args[1], args[2] if len(args) > 2 else None)
            elif fn == "set_tcp":
                c.set_tcp_offset(args[0] if args else kw["pose"])
            elif fn == "textmsg":
                c.note("textmsg: " + "".join(str(a) for a in args))
            elif fn == "sleep":
                self.sleep(float(args[0]))
            elif fn == "sync":
                self.sync()
            elif fn == "write_output_integer_register":
                c.write_output_register("int", int(args[0]), int(args[1]))
            elif fn == "write_output_float_register":
                c.write_output_register("double", int(args[0]), float(args[1]))
        except (IndexError, KeyError, TypeError, ValueError) as exc:
            raise ProgramError(f"{fn}: bad arguments ({exc})") from exc


def compile_plain(ctrl: "URControllerCore", name: str, lines: list[str], secondary: bool) -> ScriptProgram:
    """The body of a plain program (``lines`` after its ``def`` line) -> a ScriptProgram."""
    calls = []
    for ln, raw in enumerate(lines, start=2):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line == "end":
            break
        src = re.sub(r"\bp\[", "[", line)
        try:
            tree = ast.parse(src, mode="eval")
        except SyntaxError as exc:
            raise ScriptCompileError(f"line {ln}: syntax error (or not in the fake's URScript subset): {line!r}") from exc
        call = tree.body
        if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name)):
            raise ScriptCompileError(f"line {ln}: only function calls are supported by the fake: {line!r}")
        fn = call.func.id
        if fn not in STATEMENT_FUNCS:
            raise ScriptCompileError(f"line {ln}: unknown function {fn!r}")
        if secondary and fn in MOTION_FUNCS:
            raise ScriptCompileError(f"line {ln}: {fn} is not allowed in a secondary program")
        args = [_literal(a) for a in call.args]
        kw = {k.arg: _literal(k.value) for k in call.keywords}
        calls.append((fn, args, kw))
    return ScriptProgram(ctrl, name, calls)
