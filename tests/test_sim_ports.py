"""A simulated controller whose port is taken: a clear message and exit 6, not a traceback, nothing moved."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest
import yaml

from conftest import ROOT, tweak

pytest.importorskip("mujoco")


def test_port_in_use_is_named_and_exits_6(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
        data = tweak(tweak(tweak(data, "robot.name", "portsim"), "driver.rpc_port", port), "driver.host", "127.0.0.1")
        path = tmp_path / "portsim.yaml"
        path.write_text(yaml.safe_dump(data))
        env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")}
        proc = subprocess.run([sys.executable, "-m", "payload_agent.cli", "run", "--robot", str(path), "--yes"],
                              capture_output=True, text=True, env=env, timeout=120, cwd=ROOT,
                              stdin=subprocess.DEVNULL)
    assert proc.returncode == 6, proc.stderr[-2000:]
    assert f"127.0.0.1:{port}" in proc.stderr and "could not listen" in proc.stderr
    assert "Traceback" not in proc.stderr and "this is a bug" not in proc.stderr
    assert not (tmp_path / "state" / "payload-agent" / "portsim" / "runs").exists()
