"""The command line without a robot: help for every option, --version, -v/-q, JSON on stdout only,
the plan table, the no-terminal refusal, the run log, and doctor / plan --connect against nobody."""

from __future__ import annotations

import argparse
import io
import json
import logging
import socket
from pathlib import Path

import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent import cli
from payload_agent.errors import NoTerminalError
from payload_agent.output import console as console_mod
from payload_agent.output.console import Console, attach_run_log, detach_run_log


def _all_actions(parser: argparse.ArgumentParser):
    for action in parser._actions:
        yield parser.prog, action
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _all_actions(sub)


def test_every_option_has_help_and_the_top_level_says_what_the_tool_does(capsys):
    parser = cli.build_parser()
    missing = [f"{prog} {a.option_strings or a.dest}" for prog, a in _all_actions(parser)
               if a.help in (None, "", argparse.SUPPRESS) and not isinstance(a, argparse._SubParsersAction)]
    assert missing == []
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = capsys.readouterr().out
    assert "mass and centre of mass of the tool on a robot's flange" in text
    for code in ("130", "143", "  2 ", "  6 "):
        assert code in text
    for command in ("run", "plan", "doctor", "solve", "history", "report", "baseline", "calibrate", "watch"):
        assert f"    {command}" in text


def test_version_lists_the_client_libraries(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["--version"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("payload-agent 0.")
    for lib in ("ur_rtde", "pymodbus", "python-can", "canopen"):
        assert f"  {lib} " in text
    assert "drivers: " in text and "elite_ec" in text


def _robot_file(tmp_path: Path, data: dict, name: str = "robot.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_plan_json_is_the_only_thing_on_stdout_and_the_table_has_headers(tmp_path, sim_ec66_data, capsys):
    path = _robot_file(tmp_path, sim_ec66_data)
    assert cli.main(["plan", "--robot", str(path), "--json"]) == 0
    cap = capsys.readouterr()
    data = json.loads(cap.out)  # nothing else on stdout
    assert data["ok"] and data["plan"]["procedure"] == "paper_bd" and len(data["plan"]["moves"]) == 12
    assert data["plan"]["moves"][0]["expected_s"] is None and data["safety"]["approach_checked"] is False
    head = next(line for line in cap.err.splitlines() if "J1 [deg]" in line)
    assert head.split()[:3] == ["#", "type", "move"] and "speed [deg/s]" in head and "time [s]" in head
    first = next(line for line in cap.err.splitlines() if line.strip().startswith("1 "))
    assert first.split()[1:3] == ["approach", "b-j2"]  # "approach approach b-j2 start" read twice before
    assert "State of robot 'sim-ec66'" in cap.err


def test_quiet_and_verbose(tmp_path, sim_ec66_data, capsys):
    path = _robot_file(tmp_path, sim_ec66_data)
    assert cli.main(["plan", "--robot", str(path), "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert cli.main(["-q", "plan", "--robot", str(path)]) == 0
    assert capsys.readouterr().out == ""
    assert cli.main(["plan", "--robot", str(path)]) == 0
    normal = capsys.readouterr().out
    assert "Safety gate" in normal
    bad = _robot_file(tmp_path, tweak(sim_ec66_data, "procedure.speed_percnt", 5), "bad.yaml")
    assert cli.main(["plan", "--robot", str(bad), "-q"]) == 2
    err = capsys.readouterr().err
    assert "did you mean 'speed_percent'" in err and "Traceback" not in err  # errors are never quietened


def test_plan_finds_the_robot_by_name(tmp_path, sim_ec66_data, monkeypatch, capsys):
    (tmp_path / "configs").mkdir()
    _robot_file(tmp_path / "configs", sim_ec66_data, "cellbot.yaml")
    monkeypatch.chdir(tmp_path)
    assert cli.main(["plan", "--robot", "cellbot", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["config"].endswith("configs/cellbot.yaml")
    assert cli.main(["plan", "--robot", "nobot", "--json"]) == 2
    data = json.loads(capsys.readouterr().out)
    assert data["exit_code"] == 2 and "nobot.yaml" in data["error"] and "PAYLOAD_AGENT_ROBOTS" in data["error"]


def test_asker_without_a_terminal_refuses_and_names_the_flag():
    con = Console(0, stdin=io.StringIO(""), stdout=io.StringIO())
    ask = con.asker("Pass --yes or --unattended.")
    with pytest.raises(NoTerminalError) as info:
        ask("Record the loaded run now? The robot will move. [y/N] ")
    assert info.value.exit_code == 2
    assert "nothing moved" in str(info.value) and "--yes" in str(info.value) and "Record the loaded run" in str(info.value)
    assert Console(0, stdin=io.StringIO("y\n"), stdout=io.StringIO()).asker("x")("Go? ") == "y"


def test_run_log_keeps_everything_said_from_the_start(tmp_path):
    out = io.StringIO()
    con = Console(-1, stdout=out, stderr=out)  # quiet on the terminal...
    con.say("Connected: Elite Robots EC66")
    con.detail("  [loaded] 3/12 b-j3 up")
    handler = attach_run_log(tmp_path)
    try:
        con.say("Safety gate: SAFE")
        logging.getLogger("payload_agent.drivers.test").debug("a driver detail")
    finally:
        detach_run_log(handler)
    con.say("after the run")
    log = (tmp_path / console_mod.RUN_LOG_NAME).read_text()
    for line in ("Connected: Elite Robots EC66", "3/12 b-j3 up", "Safety gate: SAFE", "a driver detail"):
        assert line in log  # ...but the log has it all, including what was said before the folder existed
    assert "after the run" not in log and out.getvalue() == ""


def test_a_run_log_holds_its_own_command_and_run_only(tmp_path, ec66_data):
    """In one process (the tests, `watch`, a program that embeds the agent) neither a command that failed nor an
    earlier run of the same command (one that ended in an exception included) leaves lines in a run log."""
    port = _closed_port()
    data = tweak(tweak(tweak(ec66_data, "driver.host", "127.0.0.1"), "driver.rpc_port", port),
                 "driver.connect_timeout_s", 0.5)
    assert cli.main(["run", "--robot", str(_robot_file(tmp_path, data)), "--yes", "-q"]) == 6
    out = io.StringIO()
    con = Console(-1, stdout=out, stderr=out)
    con.say("the second command starts")
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    handler = attach_run_log(first)
    with pytest.raises(RuntimeError):
        try:
            con.say("the first run moves")
            raise RuntimeError("the first run fails")
        finally:  # as the runner ends every session
            detach_run_log(handler)
    con.say("between the runs")
    handler = attach_run_log(second)
    try:
        con.say("the second run moves")
    finally:
        detach_run_log(handler)
    one = (first / console_mod.RUN_LOG_NAME).read_text()
    two = (second / console_mod.RUN_LOG_NAME).read_text()
    assert f"127.0.0.1:{port}" not in one + two and "payload-agent: error" not in one + two  # the failed command
    assert "the second command starts" in one and "the first run moves" in one and "the second run moves" not in one
    assert "between the runs" in two and "the second run moves" in two
    assert "the first run moves" not in two and "the second command starts" not in two


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_doctor_and_plan_connect_name_host_and_port_of_an_unreachable_controller(tmp_path, ec66_data, capsys):
    port = _closed_port()
    data = tweak(tweak(tweak(ec66_data, "driver.host", "127.0.0.1"), "driver.rpc_port", port),
                 "driver.connect_timeout_s", 0.5)
    path = _robot_file(tmp_path, data)
    assert cli.main(["doctor", "--robot", str(path), "--json"]) == 6
    cap = capsys.readouterr()
    report = json.loads(cap.out)
    assert report["ready"] is False and report["reachable"] is False and report["exit_code"] == 6
    connect = next(c for c in report["checks"] if c["name"] == "connect")
    assert connect["status"] == "FAIL" and f"127.0.0.1:{port}" in connect["detail"]
    assert "NOT READY" in cap.err
    assert cli.main(["plan", "--robot", str(path), "--connect"]) == 6
    err = capsys.readouterr().err
    assert "127.0.0.1" in err and str(port) in err and "Traceback" not in err


def test_a_bad_calibrate_procedure_is_refused_by_name_before_anything_starts(tmp_path, sim_ec66_data, capsys,
                                                                            monkeypatch):
    """`calibrate --procedure`: an unknown name lists the bundled ones, a missing file says so, a malformed file
    names its own key, and a wrist procedure (no sweeps) is refused; nothing connects or moves."""
    from payload_agent.session import runner

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    started = []
    monkeypatch.setattr(runner, "run_identification", lambda *a, **k: started.append(a))
    path = _robot_file(tmp_path, sim_ec66_data)
    malformed = tmp_path / "tilted.yaml"
    malformed.write_text("name: tilted\ndescription: d\nposes:\n  p: {tool_x: up, tool_z: -up}\n"
                         "sweeps:\n  - {pose: p, joint: 2}\n")
    for bad, says in (("j2_quartet", "bundled: j2_pair, j2_quarter, j2_triple, paper_bd"),
                      (str(tmp_path / "none.yaml"), "no procedure file"),
                      (str(malformed), f"{malformed}: poses.p.tool_z: must be perpendicular"),
                      ("wrist_inertia", "sweeps: is required")):
        rc = cli.main(["calibrate", "--robot", str(path), "--yes", "--known-mass", "3", "--known-cog", "0,0,80",
                       "--procedure", bad])
        err = capsys.readouterr().err
        assert rc == 2 and "--procedure" in err and says in err, err
        assert "Traceback" not in err
    assert started == []  # refused before any session (nothing connected, nothing moved)


def test_calibrate_procedure_replaces_the_procedure_only_and_leaves_the_inertia_part_out(tmp_path, sim_ec66_data,
                                                                                         monkeypatch):
    """`calibrate --procedure`: the named procedure (a file's path made absolute, so gains.json records where it
    is), the YAML's sweep range and speed kept, no wrist moves (the calibration does not use them)."""
    from payload_agent.calibrate_args import with_procedure
    from payload_agent.configuration.config import load_config
    from payload_agent.motion.planner import make_plan

    config = load_config(_robot_file(tmp_path, tweak(sim_ec66_data, "procedure.inertia", True)))
    assert config.procedure.inertia is not None and config.procedure.name == "paper_bd"
    assert with_procedure(config, None) is config
    quarter = with_procedure(config, "j2_quarter")
    assert quarter.procedure.name == "j2_quarter" and quarter.procedure.inertia is None
    assert (quarter.procedure.sweep_from_deg, quarter.procedure.sweep_to_deg, quarter.procedure.speed_percent) == (
        config.procedure.sweep_from_deg, config.procedure.sweep_to_deg, config.procedure.speed_percent)
    plan = make_plan(quarter)
    assert not plan.wrist_moves and {(m.sweep.pose, m.sweep.joint) for m in plan.sweeps} == {("p", 2), ("q", 2)}
    copy = tmp_path / "mine.yaml"
    copy.write_text((ROOT / "procedures" / "j2_triple.yaml").read_text())
    monkeypatch.chdir(tmp_path)
    assert with_procedure(config, "mine.yaml").procedure.name == str(copy.resolve())


def test_calibrate_speed_outside_the_cap_is_refused_by_name_before_anything_starts(tmp_path, sim_ec66_data, capsys,
                                                                                    monkeypatch):
    from payload_agent.session import runner

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    started = []
    monkeypatch.setattr(runner, "run_identification", lambda *a, **k: started.append(a))
    path = _robot_file(tmp_path, sim_ec66_data)
    for bad in ("40", "0", "nan"):
        rc = cli.main(["calibrate", "--robot", str(path), "--yes", "--known-mass", "3", "--known-cog", "0,0,80",
                       "--speed-percent", bad])
        err = capsys.readouterr().err
        assert rc == 2 and "--speed-percent" in err and "safety.max_speed_percent" in err and "25 %" in err
        assert "Traceback" not in err
    assert started == []  # refused before any session (nothing connected, nothing moved)
