"""Emulation of ur_rtde's control script (rtde_control.script) on the simulated controller,
and the compiler that tells it from a plain program.

Register use (scripts/rtde_control.script, ur_rtde 1.6): the command id is read from
input_int_register_[0+off], arguments from input_double_register_[off..] and
input_int_register_[1+off]; the script writes 1 (ready) / 2 (done) to
output_int_register_[0+off], the async progress word to output_int_register_[2+off] and
results (get_tcp_offset) to output_double_register_[off..off+5].

Faults of the command channel act here: ``no_reply`` (commands are never taken),
``slow_reply`` (each command is taken ``delay_s`` late, default 1 s), ``never_finish``
(a move never reports finished: no async "finished", no "done" for a synchronous move).
"""

from __future__ import annotations

import re
import time
from typing import TYPE_CHECKING

from payload_agent.fakes.ur.constants import (CMD_GET_TCP_OFFSET, CMD_IS_STEADY, CMD_MOVEJ, CMD_PROTECTIVE_STOP,
                                              CMD_SET_PAYLOAD, CMD_SET_TARGET_PAYLOAD, CMD_SET_WATCHDOG,
                                              CMD_STOP_SCRIPT, CMD_STOPJ, CMD_STOPL, REALTIME_CMDS,
                                              UR_CONTROLLER_DONE_WITH_CMD, UR_CONTROLLER_RDY_FOR_CMD)
from payload_agent.fakes.ur.urscript import (DEF_RE, Program, ProgramError, ScriptCompileError, compile_plain,
                                             exact_time)

if TYPE_CHECKING:
    from payload_agent.fakes.ur.controller import URControllerCore


class RtdeControlProgram(Program):
    """ur_rtde's control script main loop and the commands it handles."""

    def __init__(self, ctrl: "URControllerCore", name: str, reg_off_int: int, reg_off_float: int):
        super().__init__(ctrl, name)
        self.oi = reg_off_int
        self.of = reg_off_float
        self.async_wr_count = 0
        self.async_op_id = 0
        self.async_move_t0: float | None = None
        self.async_stop_t0: float | None = None

    # registers ----------------------------------------------------------------------------------
    def in_int(self, i: int) -> int:
        return self.ctrl.read_input_register("int", i + self.oi)

    def in_dbl(self, i: int) -> float:
        return self.ctrl.read_input_register("double", i + self.of)

    def out_int(self, i: int, value: int) -> None:
        self.ctrl.write_output_register("int", i + self.oi, int(value))

    def out_dbl(self, i: int, value: float) -> None:
        self.ctrl.write_output_register("double", i + self.of, float(value))

    def write_async_progress(self, value: int) -> None:
        # same bit layout as write_async_progress_register() in rtde_control.script
        self.async_wr_count += 1
        if self.async_wr_count > 127:
            self.async_wr_count = 0
        if value == 0:
            self.async_op_id += 1
            if self.async_op_id > 127:
                self.async_op_id = 0
        reg = self.async_wr_count * 65536 + self.async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int(2, reg)

    def signal_ready(self) -> None:
        self.out_int(0, UR_CONTROLLER_RDY_FOR_CMD)

    def signal_done(self) -> None:
        self.out_int(0, UR_CONTROLLER_DONE_WITH_CMD)

    # main loop ------------------------------------------------------------------------------------
    def run(self) -> None:
        if self.ctrl.script_start_delay_s > 0.0:  # the script's preamble, before its first register write
            self.sleep(self.ctrl.script_start_delay_s)
        self.write_async_progress(-1)  # reset_async_progress()
        self.signal_ready()
        keep_running = True
        executing = False
        seen_since: float | None = None  # wall time a new command was first seen (slow_reply)
        while keep_running:
            cmd = self.in_int(0)
            if cmd in REALTIME_CMDS:
                keep_running = self.process(cmd)
                self.signal_ready()
            elif cmd == 0:
                executing, seen_since = False, None
                self.signal_ready()
            elif not executing and self._take_command(seen_since):
                keep_running = self.process(cmd)
                executing = True
            elif not executing and seen_since is None:
                seen_since = time.monotonic()
            self.poll_async()
            self.sync()

    def _take_command(self, seen_since: float | None) -> bool:
        """Whether a new command is processed now (the no_reply / slow_reply faults delay it)."""
        if self.ctrl.faults.is_active("no_reply"):
            return False
        if self.ctrl.faults.is_active("slow_reply"):
            delay = float(self.ctrl.faults.params("slow_reply").get("delay_s", 1.0))
            return seen_since is not None and time.monotonic() - seen_since >= delay
        return True

    def poll_async(self) -> None:
        st = self.ctrl.robot.snapshot()
        t = exact_time(st)
        if self.async_move_t0 is not None and t > self.async_move_t0 and not st.moving \
                and not self.ctrl.faults.is_active("never_finish"):
            self.async_move_t0 = None
            self.write_async_progress(-1)  # move_thread: signal_async_operation_finished()
        if self.async_stop_t0 is not None and t > self.async_stop_t0 and not st.moving:
            self.async_stop_t0 = None
            self.write_async_progress(-1)  # stop_thread finished

    def stop_async_move(self) -> None:
        if self.async_move_t0 is not None:
            self.async_move_t0 = None
            robot = self.ctrl.robot
            robot.stop()
            self.wait_standstill(robot.now())
            self.write_async_progress(-1)

    def process(self, cmd: int) -> bool:
        c = self.ctrl
        done = True
        if cmd == CMD_MOVEJ:
            q = [self.in_dbl(i) for i in range(6)]
            v, a = self.in_dbl(6), self.in_dbl(7)
            is_async = self.in_int(1) == 1
            c.note(f"rtde_control: movej {q} v={v} a={a} async={is_async}")
            self.stop_async_move()
            if is_async:
                self.async_move_t0 = self.start_movej(q, a, v)
                self.write_async_progress(0)  # move_thread: signal_async_operation_started()
            else:
                self.movej(q, a, v)
                done = not c.faults.is_active("never_finish")
        elif cmd in (CMD_STOPJ, CMD_STOPL):
            dec = self.in_dbl(0)
            is_async = self.in_int(1) == 1
            c.note(f"rtde_control: {'stopj' if cmd == CMD_STOPJ else 'stopl'} a={dec} async={is_async}")
            if self.async_move_t0 is not None:  # stop_async_move(): the move thread is killed
                self.async_move_t0 = None
                self.write_async_progress(-1)
            if is_async:  # exec_stopl_stopj: the stop runs in a thread, the command is done at once
                self.async_stop_t0 = self.start_stopj(dec)
                self.write_async_progress(0)
            else:
                self.stopj(dec)
        elif cmd == CMD_SET_PAYLOAD:
            mass = self.in_dbl(0)
            cog = [self.in_dbl(i) for i in (1, 2, 3)]
            # PolyScope >= 5.0 branch of the script: an all-zero cog keeps the current cog
            c.set_payload_setting(mass, None if cog == [0.0, 0.0, 0.0] else cog)
        elif cmd == CMD_SET_TARGET_PAYLOAD:
            mass = self.in_dbl(0)
            cog = [self.in_dbl(i) for i in (1, 2, 3)]
            inertia = [self.in_dbl(i) for i in range(4, 10)]
            if tuple(c.controller_version[:2]) >= (5, 10):  # the script's set_target_payload lines are tagged $5.10:
                c.set_payload_setting(mass, None if cog == [0.0, 0.0, 0.0] else cog, inertia)  # same zero-cog rule
            else:  # ur-rtde strips them for an older controller, so the command does nothing and succeeds
                c.note("rtde_control: set_target_payload stripped from the script (PolyScope < 5.10): no effect")
        elif cmd == CMD_GET_TCP_OFFSET:  # tcp_offset = get_tcp_offset(); pose_to_output_float_registers(0, ...)
            for i, v in enumerate(c.tcp_offset):
                self.out_dbl(i, v)
        elif cmd == CMD_PROTECTIVE_STOP:
            c.robot.trigger_protective_stop()
        elif cmd == CMD_SET_WATCHDOG:
            c.note(f"rtde_control: watchdog {self.in_dbl(0)} Hz (not enforced by the fake)")
        elif cmd == CMD_IS_STEADY:
            self.out_int(1, 0 if c.robot.snapshot().moving else 1)
        elif cmd == CMD_STOP_SCRIPT:
            c.record_event("stop", "stop script (rtde_control)")
            c.note("rtde_control: received stop script")
        else:
            raise ProgramError(f"ur_rtde command {cmd} is not emulated by the fake UR controller")
        if cmd != CMD_STOP_SCRIPT and done:
            self.signal_done()
        return cmd != CMD_STOP_SCRIPT


def compile_program(ctrl: "URControllerCore", text: str, secondary: bool = False) -> Program:
    """A script port's program text -> ur_rtde's control script (emulated) or a plain program."""
    lines = text.split("\n")
    m = DEF_RE.match(lines[0].rstrip()) if lines else None
    if not m:
        raise ScriptCompileError("a program must start with 'def name():' or 'sec name():'")
    name = m.group(2)
    if "$" in text:
        raise ScriptCompileError("syntax error: '$' (a version tag not removed by the client?)")
    if "def rtde_cmd():" in text and "def process_cmd(cmd):" in text:
        if secondary:
            raise ScriptCompileError("ur_rtde's control script cannot run as a secondary program")
        mi = re.search(r"global reg_offset_int = # int register offset\n(\d+)", text)
        mf = re.search(r"global reg_offset_float = # float register offset\n(\d+)", text)
        if not mi or not mf:
            raise ScriptCompileError("syntax error: register offsets were not injected into the control script")
        return RtdeControlProgram(ctrl, name, int(mi.group(1)), int(mf.group(1)))
    return compile_plain(ctrl, name, lines[1:], secondary)
