"""One exit-code rule for doctor, run and the Python API (issue 19), fault by fault.

Each fault is a real listening server on loopback in place of the Elite controller's two ports:
- a port that accepts the connection and never answers;
- something that is not an Elite controller (an HTTP server's reply to anything).
The controller cannot be talked to: `doctor` and `run` exit 6 and the API raises CommunicationError
(exit_code 6), and nothing is ever sent that could move an arm."""

from __future__ import annotations

import json
import socket

import pytest

from payload_agent import cli
from payload_agent.api import identify
from payload_agent.configuration.config import load_config
from payload_agent.errors import CommunicationError

from conftest import tweak
from loopback import LoopbackServer


def _silent(conn: socket.socket) -> None:
    conn.settimeout(0.2)
    while True:
        try:
            if not conn.recv(4096):
                return
        except socket.timeout:
            continue


def _http(conn: socket.socket) -> None:
    conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: keep-alive\r\n\r\n")
    _silent(conn)


FAULTS = {"accepts-never-answers": _silent, "not-an-elite-controller": _http}


@pytest.fixture(params=sorted(FAULTS))
def fault_robot(request, tmp_path, ec66_data):
    servers = []
    ports = []
    for _ in range(2):  # JSON-RPC and monitor
        ls = socket.create_server(("127.0.0.1", 0))
        servers.append(LoopbackServer(ls, "127.0.0.1", FAULTS[request.param]))
        ports.append(ls.getsockname()[1])
    data = tweak(ec66_data, "driver.host", "127.0.0.1")
    data = tweak(tweak(data, "driver.rpc_port", ports[0]), "driver.monitor_port", ports[1])
    data = tweak(tweak(data, "driver.connect_timeout_s", 0.5), "driver.reply_timeout_s", 0.3)
    data = tweak(data, "robot.name", f"fault-{request.param}")
    path = tmp_path / "robot.yaml"
    import yaml

    path.write_text(yaml.safe_dump(data))
    yield request.param, path
    for s in servers:
        s.close()


def test_doctor_run_and_api_agree_on_exit_6(fault_robot, capsys):
    fault, path = fault_robot
    assert cli.main(["doctor", "--robot", str(path), "--json"]) == 6, fault
    report = json.loads(capsys.readouterr().out)
    assert report["exit_code"] == 6 and report["reachable"] is False
    assert cli.main(["run", "--robot", str(path), "--unattended", "--json"]) == 6, fault
    out = json.loads(capsys.readouterr().out)
    assert out["exit_code"] == 6 and out["error_type"] == "CommunicationError"
    with pytest.raises(CommunicationError) as err:
        identify(load_config(path), unattended=True)
    assert err.value.exit_code == 6
