"""The whole product against the simulated UR5e: real ur_rtde client, simulated UR controller, loopback.

The simulated controller runs in a child process (ur_rtde's constructors hold the GIL) on a
127.0.0.x address of its own: ur_rtde's ports are fixed, so each one needs its own address.
``pick_loopback_host`` picks one whose UR ports are free right now, so parallel test runs and
the other UR tests never collide.
"""

from __future__ import annotations

import csv
import json
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rtde_control", reason="ur-rtde wheel not installed (CPython 3.11/3.12)")

from conftest import ROOT, fast_start, tweak  # noqa: E402
from payload_agent.cli import main  # noqa: E402
from payload_agent.configuration.config import parse_config  # noqa: E402
from payload_agent.errors import MotionAbortedError  # noqa: E402
from payload_agent.fakes.ur import pick_loopback_host  # noqa: E402
from payload_agent.recording.rundata import load_manifest  # noqa: E402
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification  # noqa: E402


@pytest.fixture
def sim_ur5e_data():
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text())
    data["procedure"]["inertia"] = False  # the session tests count moves; tests/test_wrist_*.py test the wrist part
    return data


def _data(sim_ur5e_data, tmp_path: Path, **changes):
    data = tweak(sim_ur5e_data, "driver.host", pick_loopback_host())
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    data.pop("watch", None)
    for path, value in changes.items():
        data = tweak(data, path.replace("__", "."), value)
    # the approach is not the subject here (tests/test_end_to_end.py keeps the shipped EC66 start): the arm starts
    # where the approach goes, and the loaded run's first move runs at 15 % (conftest.fast_start)
    return fast_start(data)


def _largest_recorded_step_s(run_dir: Path, sweep: dict) -> float:
    """The largest step between the controller timestamps of a sweep's recorded samples."""
    with open(run_dir / sweep["file"], newline="") as f:
        t = np.array([float(row["t_ctrl_s"]) for row in csv.DictReader(f)])
    return float(np.max(np.diff(t))) if len(t) > 1 else 0.0


def test_cli_run_identifies_the_simulated_ur5e_payload(sim_ur5e_data, tmp_path):
    """`payload-agent run --robot sim-ur5e.yaml --yes` as shipped (only host, folders, the simulated arm's start
    and the approach speed changed)."""
    cfg_path = tmp_path / "sim-ur5e.yaml"
    cfg_path.write_text(yaml.safe_dump(_data(sim_ur5e_data, tmp_path)))
    truth = sim_ur5e_data["simulation"]["payload"]
    # no report.html: the report is test_report's and test_end_to_end's (its plots cost seconds, not protocol)
    rc = main(["run", "--robot", str(cfg_path), "--yes", "--no-report", "--retry-sweeps", "4",
               "--result", str(tmp_path / "r.json")])
    assert rc == 0
    result = json.loads((tmp_path / "r.json").read_text())
    err_mass = result["mass_kg"] - truth["mass_kg"]
    err_cog = np.array(result["cog_mm"]) - truth["cog_mm"]
    print(f"\nsim-ur5e ({result['solver']}): mass error {1000 * err_mass:+.1f} g, "
          f"CoG error {np.round(err_cog, 2).tolist()} mm")
    assert result["solver"] == sim_ur5e_data["procedure"]["solver"]
    # within 30 g and 5 mm (seeded runs with sim-ur5e's real-arm effort noise, 1.4-2.1 N·m on joints 1-3: -7 to
    # +12 g), and within what the run itself claims
    assert abs(err_mass) < 0.03 and abs(err_mass) < 4 * result["mass_std_kg"], result
    assert np.max(np.abs(err_cog)) < 5.0 and np.all(np.abs(err_cog) < 4 * np.asarray(result["cog_std_mm"])), result
    run_dir = next((tmp_path / "runs").iterdir())
    manifest = load_manifest(run_dir)
    assert manifest["effort_unit"] == "A"
    assert manifest["controller"]["model"] == "UR5e"
    assert manifest["simulation_truth"]["mass_kg"] == truth["mass_kg"]
    assert manifest["kinematic_check"]["ok"]  # actual_TCP_pose less the TCP offset = the YAML's FK
    gap_limit_s = sim_ur5e_data["safety"].get("max_stream_gap_ms", 50) / 1000.0
    rates = []
    for phase in ("empty", "loaded"):
        sweeps = [s for s in manifest["phases"][phase]["sweeps"] if s["status"] == "complete"]
        assert [s["name"] for s in sweeps] == [f"{p}-j{j}-{d}" for p in "bd" for j in (2, 3) for d in ("up", "down")]
        for s in sweeps:
            # no unreported gap: a complete sweep's own file has no hole beyond the watchdog's limit, and its
            # statistics saw what the file holds (how many of the 500 packages a second arrive is the
            # scheduler's business on a loaded machine, not a guarantee of the agent's)
            stream = s["stream"]
            assert stream["count"] >= s["samples"] > 100 and not stream["gaps"], s
            step = _largest_recorded_step_s(run_dir, s)
            assert step <= gap_limit_s and step <= stream["largest_gap_s"] + 1e-6, (step, s)
            rates.append(stream["achieved_rate_hz"])
    print(f"RTDE rate per sweep (receive time): {min(rates):.0f}-{max(rates):.0f} Hz "
          f"(500 Hz in controller time × time_scale {sim_ur5e_data['simulation']['time_scale']})")


def test_protective_stop_mid_sweep_aborts_the_run_and_keeps_the_data(sim_ur5e_data, tmp_path):
    cfg = parse_config(_data(sim_ur5e_data, tmp_path), source="test")
    cells = []

    def out(line):
        if "[empty] 2/12" in line:  # the first sweep has just been commanded
            threading.Timer(0.4, cells[0].controller.inject_fault, ("protective_stop",)).start()

    with pytest.raises(MotionAbortedError, match="protective stop"):
        run_identification(cfg, RunOptions(assume_yes=True, report=False),
                                OperatorUI(out=out, progress=False),
                                SimulatedCellUse(on_cell=cells.append))
    run_dir = next((tmp_path / "runs").iterdir())
    manifest = load_manifest(run_dir)
    phase = manifest["phases"]["empty"]
    assert phase["status"].startswith("aborted") and "protective stop" in phase["status"]
    sweep = phase["sweeps"][0]
    # the samples up to the stop are on disk (how many a busy machine delivers in 0.4 s is not ours to promise)
    assert sweep["name"] == "b-j2-up" and sweep["status"] == "aborted" and sweep["samples"] >= 10
    lines = (run_dir / sweep["file"]).read_text().splitlines()
    assert len(lines) - 1 == sweep["samples"]
    assert "loaded" not in manifest["phases"] or not manifest["phases"]["loaded"].get("sweeps")
