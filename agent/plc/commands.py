"""`payload-agent serve --robot NAME --config serve.yaml`: the cell's PLC in charge of one robot.

The OPC UA server (always) and the Modbus register interface (when the serve config has a ``modbus``
section) run in threads of their own; the jobs they start run on the main thread, one at a time, so
SIGTERM or Ctrl-C during a job takes the session's own stop path (robot stopped, data kept) before
serve ends. One robot per serve process: several robots are several processes with their own endpoints.
"""

from __future__ import annotations

import argparse
import signal
import threading
from typing import Any, Callable


def add_parser(add: Callable[..., argparse.ArgumentParser], robot_arg: Callable[..., None]) -> None:
    p = add("serve", "let the cell's PLC run identify, verify and apply over OPC UA (and Modbus registers); "
                     "moves the robot when the PLC asks")
    robot_arg(p)
    p.add_argument("--config", required=True, metavar="SERVE_YAML",
                   help="endpoint, users (password hashes, roles) and the optional modbus section (docs/production.md, 'The PLC in charge')")


def cmd_serve(args, con) -> int:
    from payload_agent.configuration.config import load_config
    from payload_agent.configuration.paths import find_robot
    from payload_agent.plc.jobs import RobotJobs
    from payload_agent.plc.opcua_server import OpcUaServer, ServerThread
    from payload_agent.plc.serve_config import load_serve_config
    from payload_agent.recording.state import RobotState
    from payload_agent.session.preflight import preflight

    serve = load_serve_config(args.config)
    config = load_config(find_robot(args.robot))
    preflight(config, calibration=True, apply=True).require()
    if not any(u.role == "operator" for u in serve.users):
        con.warn(f"{serve.source}: no user has the operator role: no one can start a job")
    cell = None
    if config.simulation is not None:
        from payload_agent.session.simulation import SimulatedCell

        cell = SimulatedCell(config).start()
    jobs = RobotJobs(config, cell=cell, log=con.say, inline=True)
    opc = modbus = None
    stop = threading.Event()
    interrupted: list[int] = []

    def handler(signum, frame):
        first = not stop.is_set()
        stop.set()
        if jobs.busy and first:
            interrupted.append(signum)
            raise KeyboardInterrupt(f"signal {signal.Signals(signum).name} during a job")

    previous = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        opc = ServerThread(OpcUaServer(serve, [jobs], RobotState.for_config(config).root / "opcua", con.say)).start()
        if serve.modbus is not None:
            from payload_agent.plc.modbus_server import ModbusHandshakeServer

            modbus = ModbusHandshakeServer(jobs, serve.modbus.host, serve.modbus.port).start()
            con.say(f"Modbus: serving {config.robot.name} at {serve.modbus.host}:{modbus.port} (no security: keep it "
                    "on the cell's own network)")
        while not stop.is_set():
            try:
                jobs.run_pending(0.2)
            except KeyboardInterrupt:
                break
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if modbus is not None:
            modbus.stop()
        if opc is not None:
            opc.stop()
        if cell is not None:
            cell.close()
    con.say("serve: stopped" + (" (a job was interrupted: the robot was stopped, data kept)" if interrupted else ""))
    return 143 if interrupted and interrupted[0] == signal.SIGTERM else 130 if interrupted else 0


SERVE_COMMANDS: dict[str, Callable[[Any, Any], int]] = {"serve": cmd_serve}
