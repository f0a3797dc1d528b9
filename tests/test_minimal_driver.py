"""The driver contract carries a new protocol family end to end: tests/inproc_driver.py, run by the runner."""

import csv
import json
import math
import threading
import time

import numpy as np
import pytest

from conftest import short_session, start_at_first_move, tweak
from host_stall import assert_latency_within
from inproc_driver import CONTROLLERS, InProcessDriver
from payload_agent.configuration.config import parse_config
from payload_agent.drivers import registry
from payload_agent.errors import ConfigError, MotionAbortedError, SafetyError, SupervisionTrip
from payload_agent.motion.planner import make_plan
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.rundata import load_manifest
from payload_agent.session.options import QUIET
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

registry.register("inproc", InProcessDriver)


def inproc_config(data, tmp_path, name, effort_unit="Nm", **safety):
    data = tweak(data, "driver", {"type": "inproc", "name": name})
    data = tweak(data, "effort", {"unit": effort_unit, "gains_nm_per_unit": 1.0})
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    data["safety"].update(safety)
    data.pop("watch", None)
    return parse_config(data, source="inproc.yaml")


def quiet(config, on_cell=None, **kw):
    """A session that accepts the plan and says nothing."""
    return run_identification(config, RunOptions(assume_yes=True, report=False, **kw), QUIET,
                              SimulatedCellUse(on_cell=on_cell))


def test_runner_drives_the_minimal_driver_end_to_end(sim_ec66_data, tmp_path):
    data = tweak(sim_ec66_data, "simulation.payload", {"mass_kg": 1.7, "cog_mm": [-30, 45, 60]})
    outcome = quiet(inproc_config(short_session(data), tmp_path, "e2e"))  # the driver is the subject
    est = outcome.result.primary
    assert abs(est.mass_kg - 1.7) < 0.03
    assert max(abs(a - b) for a, b in zip(est.cog_mm, (-30, 45, 60))) < 5.0
    manifest = load_manifest(outcome.run_dir)
    sweeps = [s for ph in manifest["phases"].values() for s in ph["sweeps"]]
    assert sweeps and all(s["status"] == "complete" and 0.8 < s["stream"]["count"] / s["samples"] < 1.25 for s in sweeps)
    assert all(s["stream"]["achieved_rate_hz"] > 0 and not s["stream"]["gaps"] for s in sweeps)
    assert manifest["status"] == "complete"


def test_stalled_stream_stops_the_arm_and_keeps_the_data(sim_ec66_data, tmp_path, stall_probe):
    data = tweak(sim_ec66_data, "simulation.time_scale", 5)  # sweeps long enough to stall in the middle
    # the simulated arm starts where the plan's approach move goes (12 s of simulated travel saved)
    data = start_at_first_move(data)
    config = inproc_config(data, tmp_path, "stall", max_stream_gap_ms=100)
    first_sweep = next(i for i, m in enumerate(make_plan(config).moves) if m.sweep is not None)
    seen = {}

    def on_cell(cell):
        def stall_in_first_sweep():
            ctrl = cell.controller
            while sum(e.kind == "move" for e in ctrl.events) <= first_sweep or not ctrl.robot.snapshot().moving:
                time.sleep(0.002)
            seen["fault_t"] = time.monotonic()
            ctrl.inject_fault("stall_stream")
        seen["cell"] = cell
        threading.Thread(target=stall_in_first_sweep, daemon=True).start()

    with pytest.raises(SupervisionTrip) as err:
        quiet(config, on_cell=on_cell)
    report = err.value.stop_report
    assert report is not None and report.acknowledged and "stalled" in report.reason
    ctrl = seen["cell"].controller
    stop = ctrl.first_event_after("stop", seen["fault_t"])
    assert stop is not None
    assert_latency_within(stop.t - seen["fault_t"], 0.5, stall_probe, seen["fault_t"], "stop")
    assert ctrl.first_event_after("move", seen["fault_t"]) is None  # nothing moved after the fault
    run_dir = next((tmp_path / "runs").iterdir())
    manifest = load_manifest(run_dir)
    assert manifest["status"] == "incomplete" and "stalled" in manifest["stopped_because"]
    sweeps = [s for ph in manifest["phases"].values() for s in ph["sweeps"]]
    assert sweeps[-1]["status"] == "aborted" and sweeps[-1]["samples"] > 0
    assert (run_dir / sweeps[-1]["file"]).read_text().count("\n") == sweeps[-1]["samples"] + 1


def test_unattended_run_without_a_pose_check_needs_the_acknowledgement(sim_ec66_data, tmp_path):
    moved = []
    with pytest.raises(SafetyError, match="unattended_without_pose_check"):
        run_identification(inproc_config(sim_ec66_data, tmp_path, "ack"),
                           RunOptions(unattended=True, fresh_baseline=True, report=False),
                           OperatorUI(progress=False, out=lambda s: None),
                           SimulatedCellUse(on_cell=lambda c: moved.append(c)))
    assert not any(e.kind == "move" for e in moved[0].controller.events)
    assert "ack" not in CONTROLLERS  # the simulated controller was closed


def test_effort_unit_must_match_the_driver_before_connecting(sim_ec66_data, tmp_path):
    config = inproc_config(sim_ec66_data, tmp_path, "unit", effort_unit="A")
    with pytest.raises(ConfigError, match="effort.unit"):
        quiet(config)
    assert "unit" not in CONTROLLERS and not (tmp_path / "runs").exists()


def test_resume_records_only_the_unfinished_sweeps(sim_ec66_data, tmp_path):
    data = tweak(sim_ec66_data, "simulation.payload", {"mass_kg": 2.2, "cog_mm": [35, -20, 50]})
    config = inproc_config(short_session(data), tmp_path, "resume")  # resume is the subject, not the procedure
    plan = make_plan(config)

    def stop_in_loaded_run(cell):
        def watch():
            ctrl = cell.controller
            n = len(plan.moves) + 3  # the whole empty run, then into the loaded run's second sweep
            while sum(e.kind == "move" for e in ctrl.events) < n or not ctrl.robot.snapshot().moving:
                time.sleep(0.002)
            ctrl.inject_fault("protective_stop")
        threading.Thread(target=watch, daemon=True).start()

    with pytest.raises(MotionAbortedError):
        quiet(config, on_cell=stop_in_loaded_run)
    run_dir = next((tmp_path / "runs").iterdir())
    first = load_manifest(run_dir)
    assert first["status"] == "incomplete"
    done_before = {s["name"] for s in first["phases"]["loaded"]["sweeps"] if s["status"] == "complete"}
    assert first["phases"]["empty"]["status"] == "complete" and 0 < len(done_before) < len(plan.sweeps)

    moves = []
    outcome = quiet(config, resume=run_dir, on_cell=lambda c: moves.append(c))
    assert outcome.run_dir == run_dir
    sweep_moves = sum(e.kind == "move" for e in moves[0].controller.events)
    left = len(plan.sweeps) - len(done_before)
    assert sweep_moves <= 2 * left + 1  # the remaining sweeps and the moves to their starts, nothing else
    final = load_manifest(run_dir)
    assert final["status"] == "complete" and final["resumed_utc"]
    assert {s["name"] for s in final["phases"]["loaded"]["sweeps"]} == {m.sweep.name for m in plan.sweeps}
    est = outcome.result.primary
    assert abs(est.mass_kg - 2.2) < 0.03 and max(abs(a - b) for a, b in zip(est.cog_mm, (35, -20, 50))) < 5.0


def test_resume_refuses_a_changed_yaml(sim_ec66_data, tmp_path):
    config = inproc_config(sim_ec66_data, tmp_path, "changed")
    run_dir = tmp_path / "runs" / "x"
    run_dir.mkdir(parents=True)
    (run_dir / "manifest.json").write_text('{"status": "incomplete", "config_fingerprint": "0", "phases": {}}')
    with pytest.raises(ConfigError, match="changed"):
        quiet(config, resume=run_dir)


def test_resume_refusals_name_what_changed(sim_ec66_data, tmp_path):
    """--resume names the one key that changed, or the robot the run belongs to; not every compared section."""
    from payload_agent.configuration.config import config_snapshot
    from payload_agent.session.resume import config_fingerprint, load_resume

    base = tweak(sim_ec66_data, "robot.name", "cell-ec66")
    config = inproc_config(base, tmp_path, "resumed")
    run_dir = tmp_path / "runs" / "x"
    run_dir.mkdir(parents=True)

    def recorded(cfg):
        (run_dir / "manifest.json").write_text(json.dumps({
            "status": "incomplete", "robot": cfg.robot.name, "config_source": "cell/resumed.yaml",
            "config": config_snapshot(cfg), "config_fingerprint": config_fingerprint(cfg), "phases": {}}))

    recorded(inproc_config(tweak(base, "procedure.speed_percent", 5), tmp_path, "resumed"))
    with pytest.raises(ConfigError) as info:
        load_resume(config, make_plan(config), run_dir)
    text = str(info.value)
    assert "procedure.speed_percent: 5 then, 10 now" in text and "safety" not in text and "effort" not in text
    recorded(inproc_config(sim_ec66_data, tmp_path, "resumed"))  # robot.name sim-ec66
    with pytest.raises(ConfigError, match="this run belongs to sim-ec66 .*cell/resumed.yaml.*--robot sim-ec66"):
        load_resume(config, make_plan(config), run_dir)


def test_a_sweep_is_recorded_from_its_start_when_the_sample_reader_joins_late(sim_ec66_data, tmp_path, monkeypatch):
    """The scheduler holds the sample reader back just as a sweep's file opens, and what the controller sends
    meanwhile is lost but the newest state (as RTDE's receive interface keeps only its newest package). The
    sweep must still be recorded from its start, at rest: the run does not send the sweep before a sample
    taken after the file opened (seen on a loaded machine: "the sweep started at 87.92°, the plan says 90.00°")."""
    config = inproc_config(short_session(sim_ec66_data), tmp_path, "late")  # the first sweep is the subject
    plan = make_plan(config)
    first = next(i for i, m in enumerate(plan.moves) if m.sweep is not None)
    sweep = plan.moves[first]
    hold, held = threading.Event(), {}
    real_begin, real_read = RunRecorder.begin_sweep, InProcessDriver._read_sample

    def begin_sweep(self, move):
        if move.recorded_name == sweep.recorded_name and not held:
            hold.set()
        real_begin(self, move)

    def read(self, timeout_s):
        sample = real_read(self, timeout_s)
        if sample is None or not hold.is_set():
            return sample
        # read after the file opened: held back up to 1 s, or until the arm has turned 3° (it must not have)
        robot, t0 = self._ctrl.robot, time.monotonic()
        q0 = robot.snapshot().q
        while time.monotonic() - t0 < 1.0 and np.max(np.abs(robot.snapshot().q - q0)) < math.radians(3.0):
            time.sleep(0.002)
        held["s"] = time.monotonic() - t0
        hold.clear()
        newest = None
        while not self._states.empty():
            newest = self._states.get_nowait()
        if newest is not None:
            self._states.put(newest)
        return real_read(self, timeout_s)  # the newest state only

    monkeypatch.setattr(RunRecorder, "begin_sweep", begin_sweep)
    monkeypatch.setattr(InProcessDriver, "_read_sample", read)
    # a sweep that starts elsewhere cannot be segmented, and one held back for 1 s has a hole in its stream (if
    # with the arm at rest): either way the first attempt is redone and kept; it must start where the plan says
    outcome = quiet(config, retry_sweeps=1)
    phase = load_manifest(outcome.run_dir)["phases"]["empty"]
    attempt = next(s for s in phase.get("redone", []) + phase["sweeps"] if s["name"] == sweep.recorded_name)
    with open(outcome.run_dir / attempt["file"], newline="") as f:
        first_row = next(csv.DictReader(f))
    j = sweep.sweep.joint  # 1-based
    start = plan.moves[first - 1].target_rad[j - 1]
    assert abs(float(first_row[f"q{j}_rad"]) - start) < math.radians(0.05)  # at rest at the sweep's start
    assert held["s"] > 0.5  # the reader was held back, and the sweep did not go out meanwhile
