"""One session per robot: the session lock in the robot's state folder (issue 19)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from payload_agent.configuration.config import load_config
from payload_agent.errors import RobotBusyError
from payload_agent.recording.state import RobotState
from payload_agent.session.doctor import run_doctor
from payload_agent.session.robot_lock import current_holder, robot_lock
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

from conftest import ROOT


def test_a_second_session_is_refused_naming_the_holder(tmp_path):
    state = RobotState(tmp_path / "ec66")
    with robot_lock(state, "baseline", "ec66") as me:
        assert current_holder(state) == me
        with pytest.raises(RobotBusyError) as busy:
            with robot_lock(state, "run", "ec66"):
                pass  # never reached
        assert busy.value.exit_code == 3
        text = str(busy.value)
        assert f"pid {os.getpid()}" in text and "`payload-agent baseline`" in text and me.started_utc in text
        assert "sent nothing" in text
    assert current_holder(state) is None
    with robot_lock(state, "run", "ec66"):  # free again once released
        pass


def test_a_lock_left_by_a_killed_session_is_taken_over_and_said(tmp_path):
    state_dir = tmp_path / "ec66"
    script = textwrap.dedent(f"""
        import os, signal
        from pathlib import Path
        from payload_agent.recording.state import RobotState
        from payload_agent.session.robot_lock import robot_lock
        with robot_lock(RobotState(Path({str(state_dir)!r})), "run", "ec66"):
            print(os.getpid(), flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == -9, done.stderr
    dead_pid = int(done.stdout.split()[0])
    state = RobotState(state_dir)
    assert current_holder(state) is None  # the OS released it with the process
    said: list[str] = []
    with robot_lock(state, "baseline", "ec66", said.append):
        pass
    assert len(said) == 1 and f"pid {dead_pid}" in said[0] and "took over" in said[0].lower()
    assert "`payload-agent run`" in said[0]


def test_a_session_refused_by_the_lock_never_connects(tmp_path):
    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    state = RobotState.for_config(config)
    cells: list[object] = []
    with robot_lock(state, "watch", config.robot.name):
        with pytest.raises(RobotBusyError):
            run_identification(config, RunOptions(assume_yes=True, report=False),
                                       OperatorUI(out=lambda *_: None),
                                       SimulatedCellUse(on_cell=cells.append))
        report = run_doctor(config, stream_window_s=0.2)
    assert cells == []  # not even the simulated controller was started
    session = next(c for c in report.checks if c.name == "session")
    assert session.status == "FAIL" and "`payload-agent watch`" in session.detail
    assert report.exit_code == 3


def test_apply_on_a_driver_that_cannot_write_is_refused_before_anything_starts(capsys):
    """`run --apply` on CANopen (no payload write): exit 2 naming --apply; no simulated controller starts."""
    from payload_agent.cli import main

    code = main(["run", "--robot", str(ROOT / "configs" / "sim-canopen-arm.yaml"), "--yes", "--apply", "--no-report"])
    err = capsys.readouterr().err
    assert code == 2
    assert "--apply" in err and "cannot write the payload setting" in err
    assert "Simulated" not in err and "Run folder" not in err  # nothing started, nothing moved


def test_capabilities_are_known_before_connecting():
    from payload_agent.session.connection import build_driver

    caps = {name: build_driver(load_config(ROOT / "configs" / f"{name}.yaml")).capabilities()
            for name in ("sim-ec66", "sim-ur5e", "sim-ur5e-modbus", "sim-canopen-arm")}
    assert "write_payload" in caps["sim-ec66"] and "write_payload" in caps["sim-ur5e"]
    assert "write_payload" not in caps["sim-canopen-arm"]
    assert {"read_payload", "write_payload"} <= caps["sim-ur5e-modbus"]
