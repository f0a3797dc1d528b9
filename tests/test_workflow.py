"""The operator's workflow against one simulated EC66 over its real protocol (issue 5).

The first run records the empty-flange baseline and identifies the first tool; then two
tool changes through the fake, each identified unattended from the stored baseline and
written to the controller (read back); the history holds three entries; a changed
procedure invalidates the baseline; --unattended never asks.
"""

import builtins
import json
import shutil

import numpy as np
import pytest

from conftest import ROOT, short_session, tweak
from payload_agent.recording import history
from payload_agent.cli import main
from payload_agent.configuration.config import parse_config
from payload_agent.errors import BaselineError, QualityGateError
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification
from payload_agent.session.simulation import SimulatedCell
from payload_agent.recording.state import RobotState

TOOLS = {"gripper-A": (1.2, (10.0, 20.0, 60.0)), "gripper-B": (3.1, (-30.0, 40.0, 110.0)),
         "camera": (0.8, (0.0, -45.0, 35.0))}


def _data(sim_ec66_data, tmp_path):
    """The simulated EC66 on ephemeral ports with its own folders; the workflow is the subject, not the
    procedure or the approach (conftest.short_session: j2_pair, the arm starting at the first move)."""
    data = tweak(sim_ec66_data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    return short_session(data)


def _never_ask(prompt):
    raise AssertionError(f"an unattended run asked: {prompt!r}")


@pytest.fixture
def no_stdin(monkeypatch):
    monkeypatch.setattr(builtins, "input", _never_ask)


@pytest.fixture(scope="module")
def stored_baseline(tmp_path_factory):
    """`payload-agent baseline --unattended` once for the module: its state folder (the stored empty-flange
    baseline), copied by each test that starts from a stored baseline into a state folder of its own."""
    import yaml

    tmp = tmp_path_factory.mktemp("baseline")
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["procedure"]["inertia"] = False  # as the sim_ec66_data fixture: the baseline must fit the tests' plan
    data = _data(data, tmp)
    builtins_input, builtins.input = builtins.input, _never_ask
    try:
        assert main(["baseline", "--robot", _write(tmp, data), "--unattended"]) == 0
    finally:
        builtins.input = builtins_input
    return tmp / "state"


def _with_stored_baseline(stored_baseline, tmp_path):
    """This test's state folder, holding the module's stored baseline (and nothing else)."""
    shutil.copytree(stored_baseline, tmp_path / "state")


def test_first_run_stores_baseline_then_two_tool_changes_unattended_with_apply(sim_ec66_data, tmp_path,
                                                                                  no_stdin):
    data = _data(sim_ec66_data, tmp_path)
    cfg = parse_config(data, source="test")
    state = RobotState.for_config(cfg)
    cell = SimulatedCell(cfg).start()
    lines = []
    try:
        for i, (tool, (mass, cog)) in enumerate(TOOLS.items()):
            cell.change_tool(mass, cog)
            moves_before = cell.robot.snapshot().move_id
            standing = np.asarray(cell.robot.snapshot().q, float)  # where this tool goes on
            first = i == 0  # no stored baseline yet: an attended run records the empty flange first
            out = run_identification(cfg, RunOptions(unattended=not first, assume_yes=first, apply=True, tool=tool, report=False),
                                          OperatorUI(ask=_never_ask, out=lines.append),
                                          SimulatedCellUse(cell=cell))
            manifest = json.loads((out.run_dir / "manifest.json").read_text())
            if first:
                assert list(manifest["phases"]) == ["empty", "loaded"]
                assert (state.baseline_dir / "baseline.json").exists()
                assert (state.baseline_dir / "empty").is_dir()
                stored = json.loads((state.baseline_dir / "baseline.json").read_text())
                assert len(stored["joint_temperatures_c"]) == 6  # the EC monitor reports them
            else:  # the stored baseline replaced the empty run; the run folder keeps a copy of it
                assert manifest["phases"]["empty"]["from_baseline"]["dir"] == str(state.baseline_dir)
                assert manifest["baseline"]["plan_fingerprint"]
                assert all((out.run_dir / s["file"]).exists() for s in manifest["phases"]["empty"]["sweeps"])
            assert cell.robot.snapshot().move_id > moves_before
            # the loaded phase records where it started, the tool cable's rest (systematics.cable_spring)
            assert "start_joint_angles_rad" not in manifest["phases"]["empty"]
            mount = manifest["phases"]["loaded"]["start_joint_angles_rad"]
            if not first:  # the arm stood where the last run left it when this tool went on
                assert np.allclose(mount, standing, atol=1e-3), (mount, standing)
            est = out.result.primary
            assert abs(est.mass_kg - mass) < 0.03, (tool, est.mass_kg)
            assert np.max(np.abs(np.array(est.cog_mm) - cog)) < 5.0, (tool, est.cog_mm)
            # written to the controller and read back
            setting = cell.controller.payload_setting(0)
            assert setting["m"] == pytest.approx(est.mass_kg, abs=1e-4)
            assert np.allclose(setting["tool_cog"], est.cog_mm, atol=1e-3)
            assert out.applied is not None and out.applied.mass_kg == pytest.approx(est.mass_kg, abs=1e-4)
    finally:
        cell.close()
    text = "\n".join(lines)
    assert "Using the stored empty-flange baseline" in text
    assert "Controller payload setting" in text and "Difference" in text

    rows = history.entries(state.history_db)
    assert len(rows) == 3
    assert [r.tool for r in rows] == list(TOOLS)
    assert all(r.applied and r.quality_passed for r in rows)
    assert [r.baseline_run_dir is None for r in rows] == [True, False, False]
    assert main(["history", "--robot", _write(tmp_path, data)]) == 0


def test_changed_procedure_invalidates_baseline(sim_ec66_data, tmp_path, no_stdin, capsys, stored_baseline):
    data = _data(sim_ec66_data, tmp_path)
    cfg = parse_config(data, source="test")
    _with_stored_baseline(stored_baseline, tmp_path)  # recorded with this procedure on a fresh simulated EC66
    cell = SimulatedCell(cfg).start()
    try:
        changed = parse_config(tweak(data, "procedure.sweep_deg", [0, 50]), source="test")
        moves = cell.robot.snapshot().move_id
        with pytest.raises(BaselineError, match="procedure changed"):
            run_identification(changed, RunOptions(unattended=True, report=False),
                                        OperatorUI(ask=_never_ask, out=lambda s: None),
                                        SimulatedCellUse(cell=cell))
        assert cell.robot.snapshot().move_id == moves  # refused before anything moved
        # the same baseline on a robot that has warmed up by 15 °C on joint 3
        warm = [t + (15.0 if j == 2 else 0.0) for j, t in enumerate(cell.controller.joint_temperatures())]
        cell.controller.set_joint_temperatures(warm)
        with pytest.raises(BaselineError, match="joint 3 is \\+1[45].* °C"):
            run_identification(cfg, RunOptions(unattended=True, report=False),
                                    OperatorUI(ask=_never_ask, out=lambda s: None),
                                    SimulatedCellUse(cell=cell))
        assert cell.robot.snapshot().move_id == moves
    finally:
        cell.close()
    # the same through the command line: exit code 3 (not ready) and the reason on stderr
    path = _write(tmp_path, tweak(data, "procedure.sweep_deg", [0, 50]))
    assert main(["run", "--robot", path, "--unattended"]) == 3
    err = capsys.readouterr().err
    assert "baseline" in err and "procedure changed" in err


def test_unattended_without_baseline_refuses_without_asking(sim_ec66_data, tmp_path, no_stdin, capsys):
    path = _write(tmp_path, _data(sim_ec66_data, tmp_path))
    assert main(["run", "--robot", path, "--unattended"]) == 3
    assert "no stored empty-flange baseline" in capsys.readouterr().err


def _write(tmp_path, data) -> str:
    import yaml

    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_watch_runs_once_per_trigger_file_and_applies(sim_ec66_data, tmp_path, no_stdin, stored_baseline):
    trigger = tmp_path / "tool-changed"
    data = tweak(_data(sim_ec66_data, tmp_path), "watch", {"trigger": {"type": "file", "path": str(trigger)},
                                                          "poll_interval_s": 0.05})
    path = _write(tmp_path, data)
    _with_stored_baseline(stored_baseline, tmp_path)  # `baseline --unattended` exited 0 (the fixture asserts it)
    trigger.write_text("")
    assert main(["watch", "--robot", path, "--max-runs", "1", "--tool", "gripper-A"]) == 0
    assert not trigger.exists()  # consumed: one file, one run
    rows = history.entries(RobotState.for_config(parse_config(data, source="test")).history_db)
    assert len(rows) == 1 and rows[0].applied and rows[0].tool == "gripper-A"
    truth = data["simulation"]["payload"]
    assert abs(rows[0].mass_kg - truth["mass_kg"]) < 0.03


def test_watch_exits_cleanly_on_sigterm(sim_ec66_data, tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    data = tweak(_data(sim_ec66_data, tmp_path), "watch", {"trigger": {"type": "file",
                                                                      "path": str(tmp_path / "never")}})
    path = _write(tmp_path, data)
    proc = subprocess.Popen([sys.executable, "-u", "-m", "payload_agent.cli", "watch", "--robot", path],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        seen = ""
        while "wait" not in seen.lower() and time.monotonic() < deadline:  # the watch loop announces itself
            line = proc.stdout.readline()
            if not line:
                break
            seen += line
        assert "wait" in seen.lower(), seen
        proc.send_signal(signal.SIGTERM)
        rest, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, seen + rest


def test_calibrate_then_run_uses_the_fitted_gains(sim_ec66_data, tmp_path, no_stdin, capsys):
    # drives that report joint 2 three per cent high and joint 3 three per cent low
    data = tweak(_data(sim_ec66_data, tmp_path), "simulation.drive_gain_error", [1, 1.03, 0.97, 1, 1, 1])
    cfg = parse_config(data, source="test")
    ref_mass, ref_cog = 3.0, (0.0, 0.0, 80.0)
    tool_mass, tool_cog = 4.2, (30.0, -60.0, 120.0)
    cell = SimulatedCell(cfg).start()
    lines = []
    try:
        # nominal gains: the mass comes out about 3 % wrong, and the quality gate notices
        cell.change_tool(tool_mass, tool_cog)
        with pytest.raises(QualityGateError):  # ... and nothing is written to the controller, though asked
            run_identification(cfg, RunOptions(assume_yes=True, apply=True, report=False),
                                    OperatorUI(out=lines.append),
                                    SimulatedCellUse(cell=cell))
        assert cell.controller.payload_setting(0)["m"] == 0.0
        assert "Not applied: the quality checks failed" in "\n".join(lines)
        nominal = json.loads(next((tmp_path / "runs").glob("*/result.json")).read_text())
        assert abs(nominal["mass_kg"] - tool_mass) > 0.05
        # the reference payload, known
        cell.change_tool(ref_mass, ref_cog)
        from payload_agent.types import PayloadSetting

        cal = run_identification(cfg, RunOptions(mode="calibrate", unattended=True, report=False, reference=PayloadSetting(ref_mass, tuple(c / 1000 for c in ref_cog))),
                                      OperatorUI(out=lines.append),
                                      SimulatedCellUse(cell=cell))
        scale = cal.calibration.scale
        # fitted / nominal gain: the drives over-report joint 2 by 3 %, so its gain must shrink by 1/1.03
        assert scale[1] == pytest.approx(1 / 1.03, abs=0.003) and scale[2] == pytest.approx(1 / 0.97, abs=0.003)
        assert RobotState.for_config(cfg).gains_path.exists()
        # the tool again: calibrated gains, and the run says so
        cell.change_tool(tool_mass, tool_cog)
        out = run_identification(cfg, RunOptions(unattended=True, report=False),
                                      OperatorUI(out=lines.append),
                                      SimulatedCellUse(cell=cell))
    finally:
        cell.close()
    assert abs(out.result.primary.mass_kg - tool_mass) < 0.015
    assert np.max(np.abs(np.array(out.result.primary.cog_mm) - tool_cog)) < 3.0
    assert "calibration" in out.result.extra["gains_source"]
    assert any(line.startswith("Drive gains: drive gains from calibration") for line in lines)
    # the zeros of joints 2 and 3 were fitted with the gains, shown, and the tool run corrected its angles by them
    assert any(line.startswith("Joint zeros (controller − link angle") and "j2 " in line for line in lines), lines
    assert [z["joint"] for z in out.result.extra["zero_offsets"]["joints"]] == [2, 3]
    # and the reference run's friction change against the baseline, measured, shown and stored (the three-step σ)
    assert any(line.startswith("Reference run's constant-friction change") and "j2 " in line for line in lines), lines
    stored = json.loads(RobotState.for_config(cfg).gains_path.read_text())
    assert 2 in {c["joint"] for c in stored["reference_friction"]["joints"]}  # this procedure sweeps joint 2 only
