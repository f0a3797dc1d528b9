"""The runner identifies a payload through the canopen driver on six simulated CiA 402 drives."""

import threading
import time

import pytest
import yaml

from conftest import ROOT, short_session, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.errors import MotionStopped, SafetyError
from payload_agent.recording.rundata import load_manifest
from payload_agent.session.options import QUIET
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

SIM = ROOT / "configs" / "sim-canopen-arm.yaml"


def sim_config(tmp_path, **changes):
    data = yaml.safe_load(SIM.read_text())
    data = tweak(data, "simulation.time_scale", 8)  # 31 samples per simulated second: ~110 per sweep
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    for path, value in changes.items():
        data = tweak(data, path, value)
    # the canopen driver is the subject, not the procedure or the approach (conftest.short_session)
    return parse_config(short_session(data), source="sim-canopen-arm.yaml")


def move_batches(ctrl) -> int:
    """How many synchronised moves the drives started (the set-points of one move share a SYNC)."""
    times = [e.t for e in ctrl.events if e.kind == "move"]
    return sum(1 for a, b in zip([None] + times, times) if a is None or b - a > 0.005)


def quiet(config, on_cell=None, **kw):
    """A session that accepts the plan and says nothing."""
    return run_identification(config, RunOptions(assume_yes=True, report=False, **kw), QUIET,
                              SimulatedCellUse(on_cell=on_cell))


def test_canopen_arm_identifies_the_payload(tmp_path):
    config = sim_config(tmp_path, **{"simulation.payload": {"mass_kg": 1.2, "cog_mm": [-20, 35, 60]}})
    outcome = quiet(config)
    est = outcome.result.primary
    assert abs(est.mass_kg - 1.2) < 0.03, est
    assert max(abs(a - b) for a, b in zip(est.cog_mm, (-20, 35, 60))) < 5.0, est
    manifest = load_manifest(outcome.run_dir)
    assert manifest["status"] == "complete"
    sweeps = [s for ph in manifest["phases"].values() for s in ph["sweeps"]]
    assert sweeps and all(s["status"] == "complete" and s["stream"]["count"] > 50 for s in sweeps)
    assert all(s["stream"]["nominal_period_s"] == pytest.approx(1 / 250) for s in sweeps)


def test_drive_fault_mid_run_stops_every_drive_and_keeps_the_data(tmp_path):
    config = sim_config(tmp_path)
    seen = {}

    def on_cell(cell):
        ctrl = seen["ctrl"] = cell.controller

        def fault_in_first_sweep():  # the second set-point batch is the first sweep (after the approach)
            while move_batches(ctrl) < 2 or not ctrl.robot.snapshot().moving:
                time.sleep(0.002)
            time.sleep(0.05)
            seen["t"] = time.monotonic()
            ctrl.inject_fault("protective_stop", joint=3)
        threading.Thread(target=fault_in_first_sweep, daemon=True).start()

    with pytest.raises(MotionStopped) as err:  # the drive stopped itself: a motion abort (exit 4)
        quiet(config, on_cell=on_cell)
    assert err.value.exit_code == 4
    assert "EMCY from joint 3 (node 3): error code 0x8611 (following error)" in str(err.value)
    ctrl = seen["ctrl"]
    stopped = {e.detail.split(":")[0] for e in ctrl.events if e.kind == "stop" and e.t >= seen["t"]}
    assert stopped == {f"node {n}" for n in range(1, 7)}
    assert not [e for e in ctrl.events if e.kind == "move" and e.t >= seen["t"]]
    run_dir = next((tmp_path / "runs").iterdir())
    manifest = load_manifest(run_dir)
    assert manifest["status"] == "incomplete" and "0x8611" in manifest["stopped_because"]
    sweeps = [s for ph in manifest["phases"].values() for s in ph["sweeps"]]
    assert sweeps[-1]["status"] == "aborted" and sweeps[-1]["samples"] > 0
    assert (run_dir / sweeps[-1]["file"]).read_text().count("\n") == sweeps[-1]["samples"] + 1


def test_unattended_canopen_run_needs_the_pose_check_acknowledgement(tmp_path):
    cells = []
    with pytest.raises(SafetyError, match="unattended_without_pose_check"):
        run_identification(sim_config(tmp_path), RunOptions(unattended=True, fresh_baseline=True, report=False),
                                                 OperatorUI(progress=False, out=lambda s: None),
                                                 SimulatedCellUse(on_cell=cells.append))
    assert not [e for e in cells[0].controller.events if e.kind == "move"]  # refused before any motion
