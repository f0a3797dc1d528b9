"""The simulated controller's dashboard server (port 29999): one text line in, one line out.

Replies as PolyScope 5 does to the commands ur_rtde's DashboardClient and the driver send
(wording sources and the UNVERIFIED ones: docs/sources.md, "UR / ur_rtde"). The dashboard is
independent of RTDE and of the running program: it answers while the RTDE stream stalls or a
program hangs, which is why the driver stops the arm through it when RTDE is gone.
"""

from __future__ import annotations

import socket
from typing import TYPE_CHECKING

from payload_agent.fakes.tcp_server import read_lines
from payload_agent.fakes.ur.constants import (ROBOT_MODE_IDLE, ROBOT_MODE_NAMES, ROBOT_MODE_POWER_OFF,
                                              ROBOT_MODE_POWER_ON, ROBOT_MODE_RUNNING, RUNTIME_PLAYING,
                                              SAFETY_MODE_NAMES, UNLOCK_PROTECTIVE_STOP_DELAY_S)

if TYPE_CHECKING:
    from payload_agent.fakes.ur.controller import URControllerCore

GREETING = b"Connected: Universal Robots Dashboard Server\n"


def serve_dashboard(ctrl: "URControllerCore", conn: socket.socket) -> None:
    conn.sendall(GREETING)
    for line in read_lines(conn, ctrl.closing.is_set, 4096):
        reply, close = dashboard_reply(ctrl, line.decode(errors="replace").rstrip("\r"))
        conn.sendall((reply + "\n").encode())
        if close:
            return


def _status(ctrl: "URControllerCore", st) -> dict[str, str]:
    ver = ".".join(str(v) for v in ctrl.controller_version)
    with ctrl.lock:
        running = ctrl.runtime_state == RUNTIME_PLAYING
        name = ctrl.program_name or "<unnamed>"
        rmode = ctrl.robot_mode
    smode = ctrl.safety(st)[0]
    return {
        "PolyscopeVersion": f"URSoftware {ver} (Jan 19 2022)",
        "version": f"Version: {ver}",
        "get serial number": ctrl.serial_number,
        "get robot model": ctrl.robot_model,
        "is in remote control": "true" if ctrl.remote_control else "false",
        "robotmode": f"Robotmode: {ROBOT_MODE_NAMES.get(rmode, 'UNKNOWN')}",
        "safetymode": f"Safetymode: {SAFETY_MODE_NAMES.get(smode, 'UNKNOWN')}",
        "safetystatus": f"Safetystatus: {SAFETY_MODE_NAMES.get(smode, 'UNKNOWN')}",
        "programState": f"{'PLAYING' if running else 'STOPPED'} {name}",
        "running": f"Program running: {'true' if running else 'false'}",
        "get loaded program": "No program loaded",
        "isProgramSaved": f"true {name}",
        "close popup": "closing popup",
        "close safety popup": "closing safety popup",
        "get operational mode": "NONE",
    }


def dashboard_reply(ctrl: "URControllerCore", cmd: str) -> tuple[str, bool]:
    """One dashboard command -> (reply line, close the connection)."""
    st = ctrl.robot.snapshot()
    simple = _status(ctrl, st)
    if cmd in simple:
        return simple[cmd], False
    if cmd == "quit":
        return "Disconnected", True
    if cmd == "stop":  # accepted in Local mode too (UNVERIFIED): stopping never needs Remote Control
        ctrl.record_event("stop", "dashboard stop")
        ctrl.stop_program("dashboard stop", wait=True)
        return "Stopped", False
    if cmd == "play":
        return "Failed to execute: play", False  # no program is ever loaded on this fake
    if cmd == "pause":
        return "Failed to execute: pause", False
    if cmd == "power on":
        with ctrl.lock:
            if st.estop:
                return "Failed to execute: power on", False
            if ctrl.robot_mode == ROBOT_MODE_POWER_OFF:
                ctrl.robot_mode = ROBOT_MODE_IDLE
        return "Powering on", False
    if cmd == "power off":
        ctrl.stop_program("power off", wait=True)
        with ctrl.lock:
            ctrl.robot_mode = ROBOT_MODE_POWER_OFF
        ctrl.robot.set_servo(False)
        return "Powering off", False
    if cmd == "brake release":
        with ctrl.lock:
            if ctrl.robot_mode in (ROBOT_MODE_IDLE, ROBOT_MODE_POWER_ON) and not st.estop:
                ctrl.robot_mode = ROBOT_MODE_RUNNING
                ctrl.robot.set_servo(True)
        return "Brake releasing", False
    if cmd == "unlock protective stop":
        if not st.protective_stop:
            return "Protective stop releasing", False
        since = ctrl.protective_since if ctrl.protective_since is not None else st.t
        if st.t - since < UNLOCK_PROTECTIVE_STOP_DELAY_S:
            return ("Cannot unlock protective stop until 5s after occurrence. "
                    "Always inspect cause of protective stop before unlocking"), False
        ctrl.robot.reset_safety()
        ctrl.protective_since = None
        return "Protective stop releasing", False
    if cmd == "restart safety":
        return "Restarting safety", False
    if cmd.startswith("load "):
        return f"File not found: {cmd[5:]}", False
    if cmd.startswith("addToLog "):
        return "Added log message", False
    if cmd.startswith("popup "):
        return "showing popup", False
    return f"could not understand: '{cmd}'", False
