"""An agent killed with SIGKILL mid-sweep leaves a readable run folder, and `run --resume` completes it."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from conftest import ROOT, short_session
from payload_agent.recording.rundata import load_manifest

AGENT = [sys.executable, "-m", "payload_agent.cli"]


def sim_yaml(tmp_path: Path, time_scale: float | None = 10) -> Path:
    """The shipped sim-ec66.yaml on ephemeral ports; ``time_scale`` 10 is slow enough to be killed in the
    middle of a sweep, None keeps the shipped one. The simulation section is not part of the resume
    fingerprint (the robot, effort, driver, procedure and safety sections are), so the resumed run may
    simulate faster."""
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["driver"].update(rpc_port=0, monitor_port=0)  # ephemeral ports: no clash with other simulations
    data["procedure"]["inertia"] = False  # its wrist moves (tests/test_wrist_*) would double the resumed run
    if time_scale is not None:
        data["simulation"]["time_scale"] = time_scale
    data["storage"] = {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")}
    data.pop("watch", None)
    data = short_session(data)  # the kill and the resume are the subject (conftest.short_session)
    path = tmp_path / "sim-ec66.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def wait_for_a_sweep_with_samples(runs: Path, proc: subprocess.Popen, timeout_s: float = 120.0) -> Path:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[0]
        for run in runs.glob("*") if runs.exists() else []:
            try:
                manifest = json.loads((run / "manifest.json").read_text())
            except (OSError, ValueError):
                continue
            sweeps = [s for ph in manifest.get("phases", {}).values() for s in ph.get("sweeps", [])]
            recording = [s for s in sweeps if s.get("status") == "recording"]
            if len(sweeps) >= 3 and recording and (run / recording[0]["file"]).stat().st_size > 20_000:
                return run
        time.sleep(0.05)
    raise AssertionError("no sweep was being recorded in time")


def test_sigkill_mid_sweep_then_resume(tmp_path):
    robot = sim_yaml(tmp_path)
    proc = subprocess.Popen([*AGENT, "run", "--robot", str(robot), "--yes", "--no-report"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        run = wait_for_a_sweep_with_samples(tmp_path / "runs", proc)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    manifest = load_manifest(run)  # readable: written atomically
    assert manifest["status"] != "complete"
    cut = next(s for ph in manifest["phases"].values() for s in ph["sweeps"] if s["status"] == "recording")
    lines = (run / cut["file"]).read_text().splitlines()
    assert len(lines) > 10 and lines[0].startswith("t_ctrl_s")
    for line in lines[1:-1]:  # every complete line is a full sample (the last one may be cut)
        assert len(line.split(",")) == 14
    sim_yaml(tmp_path, time_scale=None)  # the same robot YAML, its simulation at the shipped speed
    done = subprocess.run([*AGENT, "run", "--robot", str(robot), "--yes", "--no-report", "--resume", str(run)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    final = load_manifest(run)
    assert final["status"] == "complete"
    result = json.loads((run / "result.json").read_text())
    assert abs(result["mass_kg"] - 2.0) < 0.03
