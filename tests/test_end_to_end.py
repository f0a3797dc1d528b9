"""The whole product against the simulated EC66 over its real protocol on loopback."""

import json
import threading

import numpy as np
import pytest

from conftest import short_session, tweak
from payload_agent.cli import main
from payload_agent.configuration.config import parse_config
from payload_agent.errors import MotionAbortedError
from payload_agent.recording.rundata import load_manifest
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification


def _config(data, tmp_path, **changes):
    data = tweak(data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    for path, value in changes.items():
        data = tweak(data, path.replace("__", "."), value)
    return parse_config(data, source="test")


def test_identifies_simulated_payload_over_the_protocol(sim_ec66_data, tmp_path):
    # the shipped sim-ec66.yaml as it is (10 % both ways, general solver, noise 0.3 N·m, friction on), loopback ports
    cfg = _config(sim_ec66_data, tmp_path)
    truth = sim_ec66_data["simulation"]["payload"]
    lines = []
    outcome = run_identification(cfg, RunOptions(assume_yes=True, result_path=tmp_path / "r.json"),
                                      OperatorUI(out=lines.append))
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["solver"] == "general" and "three-step" in result["estimates"]
    assert result["quality"]["passed"] and abs(result["mass_kg"] - truth["mass_kg"]) < 4 * result["mass_std_kg"]
    assert abs(result["mass_kg"] - truth["mass_kg"]) < 0.03, result
    assert np.max(np.abs(np.array(result["cog_mm"]) - truth["cog_mm"])) < 5.0, result
    assert set(result["residual_rms_nm"]) and all(v < 1.0 for v in result["residual_rms_nm"].values())
    manifest = load_manifest(outcome.run_dir)
    assert manifest["phases"]["empty"]["status"] == "complete"
    sweeps = manifest["phases"]["loaded"]["sweeps"]
    assert [s["name"] for s in sweeps] == [f"{p}-j{j}-{d}" for p in "bd" for j in (2, 3) for d in ("up", "down")]
    assert all(s["status"] == "complete" and s["samples"] > 200 for s in sweeps)
    assert (outcome.run_dir / "report.html").exists()
    assert (outcome.run_dir / "result.json").exists()
    # the offline analysis of the recorded run gives the same answer
    assert main(["solve", str(outcome.run_dir), "--result", str(tmp_path / "again.json")]) == 0
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["mass_kg"] == pytest.approx(result["mass_kg"], rel=1e-12)


def test_estop_mid_sweep_stops_and_keeps_data(sim_ec66_data, tmp_path):
    # slow sweeps (3 %) so that the stop lands mid-sweep; one direction only and j2_pair's two sweeps
    # (conftest.short_session): a quarter of the shipped empty run to wait for
    cfg = _config(short_session(sim_ec66_data), tmp_path, procedure__speed_percent=3, procedure__bidirectional=False)
    cells = []

    def out(line):
        if "[loaded] 2/4" in line:  # the first loaded sweep has just been commanded
            cell = cells[0]
            threading.Timer(0.15, cell.controller.press_estop).start()

    with pytest.raises(MotionAbortedError):
        run_identification(cfg, RunOptions(assume_yes=True, report=False),
                                OperatorUI(out=out),
                                SimulatedCellUse(on_cell=cells.append))
    cell = cells[0]
    assert not cell.robot.snapshot().moving
    run_dir = next((tmp_path / "runs").iterdir())
    manifest = load_manifest(run_dir)
    assert manifest["phases"]["empty"]["status"] == "complete"
    assert manifest["phases"]["loaded"]["status"].startswith("aborted")
    sweep = manifest["phases"]["loaded"]["sweeps"][0]
    assert sweep["status"] == "aborted" and sweep["samples"] > 0
    lines = (run_dir / sweep["file"]).read_text().splitlines()
    assert len(lines) - 1 == sweep["samples"]


def test_operator_declines_nothing_moves(sim_ec66_data, tmp_path):
    cfg = _config(sim_ec66_data, tmp_path)
    cells = []
    with pytest.raises(MotionAbortedError, match="declined"):
        run_identification(cfg, RunOptions(),
                                OperatorUI(ask=lambda prompt: "n", out=lambda s: None),
                                SimulatedCellUse(on_cell=cells.append))
    assert cells[0].robot.snapshot().move_id == 0
