"""The command line against the simulated EC66 (real Elite protocol on loopback), as an integrator runs it:
no terminal, SIGTERM at the prompt, a run with --json whose state lands in the XDG state folder, then solve,
history and report on what it left, and doctor, which never moves anything."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml

from conftest import ROOT, fast_start, short_session, tweak
from payload_agent.configuration.config import load_config

pytest.importorskip("mujoco")


def sim_robot(tmp_path: Path, name: str = "clisim", short=fast_start) -> Path:
    """The shipped sim-ec66.yaml, no storage paths (state goes to $XDG_STATE_HOME), a faster clock and a
    generous stream-gap limit so that a loaded CI machine does not trip the supervision; the command line is the
    subject, not the approach (conftest.fast_start; ``short=short_session``: nor the procedure)."""
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "robot.name", name)
    data = tweak(tweak(data, "simulation.time_scale", 25), "safety.max_stream_gap_ms", 1000)
    data = tweak(data, "procedure.inertia", False)  # its wrist moves double a session (tests/test_wrist_*)
    data = short(data)
    path = tmp_path / "robots" / f"{name}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data))
    return path


def _env(tmp_path: Path) -> dict[str, str]:
    return {**os.environ, "XDG_STATE_HOME": str(tmp_path / "xdg-state"), "PYTHONUNBUFFERED": "1",
            "PYTHONFAULTHANDLER": "1"}


def _cli(args: list[str], env: dict, stdin=subprocess.DEVNULL, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "payload_agent.cli", *args], stdin=stdin, capture_output=True,
                          text=True, env=env, timeout=timeout, cwd=ROOT)


def _runs(tmp_path: Path, robot: str = "clisim") -> list[Path]:
    runs = tmp_path / "xdg-state" / "payload-agent" / robot / "runs"
    return sorted(runs.iterdir()) if runs.exists() else []


def test_no_terminal_refuses_says_what_to_pass_and_nothing_moves(tmp_path):
    proc = _cli(["run", "--robot", str(sim_robot(tmp_path))], _env(tmp_path))
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "no terminal" in proc.stderr and "--yes" in proc.stderr and "--unattended" in proc.stderr
    assert "nothing moved" in proc.stderr and "Traceback" not in proc.stderr + proc.stdout
    assert _runs(tmp_path) == []  # no run folder for a run where nothing moved


def test_sigterm_at_the_prompt_exits_143_without_a_run_folder(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "payload_agent.cli", "run", "--robot", str(sim_robot(tmp_path))],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(tmp_path), cwd=ROOT)
    seen: list[str] = []
    asked = threading.Event()

    def read():
        while True:
            ch = proc.stdout.read(1)
            if not ch:
                return
            seen.append(ch)
            if "".join(seen[-8:]).endswith("[y/N] "):
                asked.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        assert asked.wait(120), "".join(seen)[-2000:]
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(60)
        except subprocess.TimeoutExpired:  # hung on the way out (seen once in CI): every thread's stack, then fail
            proc.send_signal(signal.SIGABRT)  # PYTHONFAULTHANDLER: the tracebacks go to stderr
            proc.wait(10)
            pytest.fail("no exit within 60 s of SIGTERM at the prompt; the process's threads:\n"
                        + proc.stderr.read()[-6000:])
    finally:
        if proc.poll() is None:
            proc.kill()
    err = proc.stderr.read()
    assert rc == 143, err
    assert "terminated" in err and "Traceback" not in err
    assert _runs(tmp_path) == []


class _Env:
    """os.environ changes for a module-scoped fixture (monkeypatch is per test)."""

    def __init__(self, **values: str):
        self.values, self.saved = values, {}

    def __enter__(self):
        for k, v in self.values.items():
            self.saved[k] = os.environ.get(k)
            os.environ[k] = v
        return self

    def __exit__(self, *exc):
        for k, v in self.saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _main(args: list[str], capsys) -> tuple[int, str, str]:
    from payload_agent import cli

    rc = cli.main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """One `run --yes --json` through the CLI (in this process); its state lands in $XDG_STATE_HOME/payload-agent/<robot>/."""
    import contextlib
    import io

    from payload_agent import cli

    tmp = tmp_path_factory.mktemp("clirun")
    robot = sim_robot(tmp)
    out, err = io.StringIO(), io.StringIO()
    with _Env(XDG_STATE_HOME=str(tmp / "xdg-state")), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        # --no-report: the report is written by the `report` command below (test_solve_history_and_report...)
        rc = cli.main(["run", "--robot", str(robot), "--yes", "--json", "--no-report", "--tool", "gripper-A"])
    return tmp, robot, rc, out.getvalue(), err.getvalue()


def test_run_json_on_stdout_human_text_on_stderr_state_beside_the_robot(cli_run):
    tmp, robot, rc, stdout, stderr = cli_run
    assert rc == 0, stderr[-3000:]
    data = json.loads(stdout)  # stdout is exactly one JSON document
    state = tmp / "xdg-state" / "payload-agent" / "clisim"
    run_dir = Path(data["run_dir"])
    assert run_dir.parent == state / "runs" and (run_dir / "result.json").exists()
    assert (state / "baseline" / "baseline.json").exists() and (state / "history.sqlite").exists()
    assert f"State of robot 'clisim': {state}" in stderr and f"Run folder: {run_dir}" in stderr
    truth = data["simulation_truth"]
    assert data["result"]["mass_kg"] == pytest.approx(truth["mass_kg"], abs=0.05)
    values = data["controller_values"]
    assert values["controller"] == "Elite EC controller" and values["cog_unit"] == "mm"
    assert values["cog"] == pytest.approx(data["result"]["cog_mm"])
    assert "Values for the Elite EC controller" in stderr and "{" not in stderr.splitlines()[0]


def test_solve_history_and_report_on_the_recorded_run(cli_run, capsys, monkeypatch):
    tmp, robot, rc, stdout, _ = cli_run
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp / "xdg-state"))
    run_dir = Path(json.loads(stdout)["run_dir"])
    own = hashlib.sha256((run_dir / "result.json").read_bytes()).hexdigest()

    def history() -> list:
        rc, out, _ = _main(["history", "--robot", str(robot), "--json"], capsys)
        assert rc == 0
        return json.loads(out)["entries"]

    assert len(history()) == 1
    rc, out, err = _main(["solve", str(run_dir), "--solver", "three-step", "--json"], capsys)
    assert rc in (0, 5), err
    solved = json.loads(out)
    new = Path(solved["result_file"])
    assert new.parent == run_dir and new.name.startswith("result-solve-")
    assert solved["result"]["solve"]["solver"] == "three-step"
    assert "own empty phase" in solved["result"]["solve"]["baseline"]
    assert hashlib.sha256((run_dir / "result.json").read_bytes()).hexdigest() == own  # never overwritten
    assert len(history()) == 1  # left alone...
    _main(["solve", str(run_dir), "--history", "--robot", str(robot), "--tool", "gripper-A"], capsys)
    entries = history()
    assert len(entries) == 2 and entries[-1]["tool"] == "gripper-A"  # ...unless asked
    rc, out, err = _main(["report", str(run_dir), "--out", str(tmp / "r.html")], capsys)
    assert rc == 0 and (tmp / "r.html").read_text().startswith("<!DOCTYPE html>")


def test_runs_by_name_solve_with_the_runs_solver_and_report_out_checked(cli_run, capsys, monkeypatch):
    """history names the run folders; solve and report take that name; solve uses the solver the run used
    (its manifest), not the YAML's; report --out never creates a missing folder; 'Run folder:' is said once."""
    import shutil

    tmp, robot, rc, stdout, stderr = cli_run
    assert stderr.count("Run folder:") == 1
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp / "xdg-state"))
    run_dir = Path(json.loads(stdout)["run_dir"])
    assert json.loads((run_dir / "manifest.json").read_text())["solver"] == "general"
    rc, out, err = _main(["history", "--robot", str(robot)], capsys)
    assert rc == 0 and run_dir.name in out and str(run_dir.parent) in out
    rc, out, err = _main(["plan", "--robot", str(robot)], capsys)  # the stored baseline's controller line
    assert rc == 0 and "Stored baseline: recorded" in out and "serial ;" not in out and "serial not reported" in out
    # a copy of the run recorded with --solver three-step (the YAML says general)
    other = run_dir.parent / (run_dir.name + "-3step")
    shutil.copytree(run_dir, other)
    manifest = json.loads((other / "manifest.json").read_text())
    (other / "manifest.json").write_text(json.dumps({**manifest, "solver": "three-step"}))
    rc, out, err = _main(["solve", other.name, "--json"], capsys)  # by name, from anywhere
    assert rc in (0, 5), err
    solved = json.loads(out)
    assert solved["result"]["solve"]["solver"] == "three-step" and Path(solved["result_file"]).parent == other
    rc, out, err = _main(["solve", "no-such-run", "--json"], capsys)
    assert rc == 2 and "no-such-run" in err and str(run_dir.parent) in err
    missing = tmp / "missing-dir"
    rc, out, err = _main(["report", run_dir.name, "--out", str(missing / "x.html")], capsys)
    assert rc == 2 and f"the folder {missing} does not exist" in err and not missing.exists()
    rc, out, err = _main(["report", run_dir.name, "--out", str(tmp / "by-name.html")], capsys)
    assert rc == 0 and (tmp / "by-name.html").is_file()


def test_readme_calibrate_example_works_on_the_simulator(tmp_path, capsys, monkeypatch):
    """README: `calibrate --known-mass 3.0 --known-cog 0,0,80` on a simulated robot mounts that reference
    (the YAML's simulated tool weighs something else) and fits the gains: exit 0, the truth is the reference."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg-state"))
    robot = sim_robot(tmp_path, "calsim", short=short_session)
    assert yaml.safe_load(robot.read_text())["simulation"]["payload"]["mass_kg"] != 3.0
    rc, out, err = _main(["calibrate", "--robot", str(robot), "--yes", "--known-mass", "3.0", "--known-cog",
                          "0,0,80"], capsys)
    assert rc == 0, err[-3000:]
    assert "the reference payload 3 kg at [0,0,80] mm is the simulated tool" in out + err
    gains = json.loads((tmp_path / "xdg-state" / "payload-agent" / "calsim" / "gains.json").read_text())
    assert gains["reference_mass_kg"] == 3.0 and 2 in gains["fitted_joints"]


def test_calibrate_on_a_named_procedure_sweeps_it_and_records_it(tmp_path, capsys, monkeypatch):
    """`calibrate --procedure j2_pair` on the simulated EC66 whose YAML says paper_bd: the calibration run sweeps
    j2_pair's two joint-2 sweeps (no inertia part), gains.json records the procedure it swept, and the plan names
    it (issue 22: how much of the DH lengths a calibration absorbs depends on where it swept)."""
    from payload_agent.configuration.procedure import load_procedure
    from payload_agent.session import target

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg-state"))
    robot = sim_robot(tmp_path, "calproc")
    assert yaml.safe_load(robot.read_text())["procedure"]["name"] == "paper_bd"
    rc, out, err = _main(["calibrate", "--robot", str(robot), "--yes", "--known-mass", "3.0", "--known-cog",
                          "0,0,80", "--procedure", "j2_pair", "--no-report"], capsys)
    assert rc == 0, err[-3000:]
    gains = json.loads((tmp_path / "xdg-state" / "payload-agent" / "calproc" / "gains.json").read_text())
    assert gains["procedure"] == {"name": "j2_pair", "fingerprint": load_procedure("j2_pair").fingerprint,
                                  "sweep_deg": [0.0, 55.0], "speed_percent": 10.0}
    manifest = json.loads((Path(gains["run_dir"]) / "manifest.json").read_text())
    assert manifest["procedure"] == "j2_pair"
    sweeps = {(m["sweep"]["pose"], m["sweep"]["joint"]) for m in manifest["plan"] if m.get("sweep")}
    assert sweeps == {(s.pose, s.joint) for s in load_procedure("j2_pair").sweeps}
    assert not any(m.get("wrist") for m in manifest["plan"])
    assert "it swept j2_pair, 0–55°, sweep 10 %" in target.noise_for(load_config(robot))[1]


def test_doctor_connects_identifies_measures_and_never_moves(tmp_path, monkeypatch):
    from payload_agent.session.doctor import run_doctor
    from payload_agent.session.simulation import SimulatedCell

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    config = load_config(sim_robot(tmp_path, "docsim"))
    cell = SimulatedCell(config).start()
    try:
        report = run_doctor(config, cell=cell, stream_window_s=1.0)
        events = [e.kind for e in cell.controller.events]
    finally:
        cell.close()
    checks = {c.name: c for c in report.checks}
    assert checks["identify"].status == "ok" and "EC66" in checks["identify"].detail
    assert checks["state"].status == "ok"
    assert checks["sample stream"].status == "ok" and checks["sample stream"].data["rate_hz"] > 100
    stream = checks["sample stream"].detail  # two clocks, each labelled: never one number with the other's unit
    assert stream.startswith("simulated clock: ") and "; wall clock: " in stream and "faster than wall time" in stream
    assert "serial ?" not in checks["identify"].detail
    assert checks["kinematic cross-check"].status == "ok"
    assert checks["payload setting"].status == "info" and "kg" in checks["payload setting"].detail
    assert checks["stored baseline"].status == "warn" and "no stored" in checks["stored baseline"].detail
    assert checks["drive-gain calibration"].status == "info"
    assert report.ready and not report.ready_unattended and report.exit_code == 0
    assert "move" not in events and "stop" not in events  # doctor never commands anything
    # a wrong DH sign: the cross-check fails and the robot is not ready
    bad = config.robot.dh[1].__class__(-config.robot.dh[1].a_m, config.robot.dh[1].d_m, config.robot.dh[1].alpha_rad,
                                        config.robot.dh[1].offset_rad)
    import dataclasses

    wrong = dataclasses.replace(config, robot=dataclasses.replace(config.robot, dh=(config.robot.dh[0], bad,
                                                                                     *config.robot.dh[2:])))
    cell = SimulatedCell(config).start()
    try:
        report = run_doctor(wrong, cell=cell, stream_window_s=0.5)
    finally:
        cell.close()
    cross = next(c for c in report.checks if c.name == "kinematic cross-check")
    assert cross.status == "FAIL" and "a2" in cross.detail and not report.ready
    assert report.exit_code == (3 if report.config_ok else 2)


def test_calibrate_runs_its_sweeps_at_the_speed_given(tmp_path, capsys, monkeypatch):
    """`calibrate --speed-percent 5`: the calibration run's sweeps at 5 % (the YAML says 10 %), its gains stored;
    a slower calibration pins the gains tighter for every later run (issue 22). On j2_pair (conftest.short_session)
    and without the report: the sweeps' speed is the subject, not paper_bd's four sweeps or the report's figures
    (the named-procedure test below sweeps j2_pair too; the README example above writes its report)."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg-state"))
    robot = sim_robot(tmp_path, "calslow", short=short_session)
    assert yaml.safe_load(robot.read_text())["procedure"]["speed_percent"] == 10
    rc, out, err = _main(["calibrate", "--robot", str(robot), "--yes", "--known-mass", "3.0", "--known-cog",
                          "0,0,80", "--speed-percent", "5", "--no-report"], capsys)
    assert rc == 0, err[-3000:]
    gains = json.loads((tmp_path / "xdg-state" / "payload-agent" / "calslow" / "gains.json").read_text())
    manifest = json.loads((Path(gains["run_dir"]) / "manifest.json").read_text())
    sweeps = [m for m in manifest["plan"] if m.get("sweep")]
    assert sweeps and {m["sweep"]["speed_percent"] for m in sweeps} == {5.0}
    assert [m["speed_deg_s"] for m in sweeps] == pytest.approx([0.05 * 144] * len(sweeps))
