"""What the operator reads: stop reasons as sentences, only the failed checks after FAILED, no float noise."""

import json

import pytest

from payload_agent import cli
from payload_agent.errors import CommunicationError, MotionAbortedError, Terminated
from payload_agent.output.stop_text import readable, stop_sentence
from payload_agent.solvers.results import Estimate, RunResult, format_table


@pytest.mark.parametrize("exc, expected", [
    (KeyboardInterrupt("signal SIGTERM during a run"), "stopped by signal SIGTERM during a run"),
    (KeyboardInterrupt(), "interrupted by Ctrl-C"),
    (Terminated(), "terminated by SIGTERM"),
    (MotionAbortedError("protective stop on joint 3"), "motion aborted: protective stop on joint 3"),
    (CommunicationError("the controller closed the connection"),
     "communication failure: the controller closed the connection"),
])
def test_stop_reasons_are_sentences(exc, expected):
    assert stop_sentence(exc) == expected


def test_a_bug_keeps_its_class_name_for_the_bug_report():
    assert stop_sentence(ValueError("x")) == "unexpected error (a bug, ValueError): x"


def test_older_manifests_read_as_sentences():
    assert readable("KeyboardInterrupt: signal SIGTERM during a run") == "stopped by signal SIGTERM during a run"
    assert readable("SupervisionTrip: motion stopped") == "supervision trip: motion stopped"
    assert readable("MotionAbortedError: e-stop") == "motion aborted: e-stop"
    assert readable("the sample stream stalled") == "the sample stream stalled"


def test_failed_lists_only_the_failed_checks():
    result = RunResult("r", "d", Estimate("general", 2.0, (0.0, 0.0, 0.08)), quality={"passed": False, "checks": [
        {"check": "pose b vs d", "passed": True, "z": 0.4},
        {"check": "residual whiteness", "passed": False},
        {"check": "mass significance", "passed": False, "z": 1.2}]})
    line = next(l for l in format_table(result).splitlines() if l.startswith("quality checks"))
    assert line == "quality checks FAILED (residual whiteness, mass significance: z = +1.2)"
    result.quality["passed"] = True
    line = next(l for l in format_table(result).splitlines() if l.startswith("quality checks"))
    assert "pose b vs d" in line  # a passed verdict shows every check


@pytest.mark.parametrize("robot", ["sim-ec66", "sim-ur5e", "sim-canopen-arm", "ur5e-modbus"])
def test_plan_json_has_no_float_noise(robot, capsys):
    cli.main(["plan", "--robot", robot, "--json", "--from-deg", "0,-90,90,0,90,0"])
    data = json.loads(capsys.readouterr().out)
    for move in data["plan"]["moves"]:
        assert all(round(v, 4) == v for v in move["target_deg"]), move
        assert move["expected_s"] is None or round(move["expected_s"], 3) == move["expected_s"]
    assert any(abs(abs(v) - 180) < 1e-9 for m in data["plan"]["moves"] for v in m["target_deg"]) or robot != "sim-ec66"


def test_pendant_values_in_the_units_of_each_controllers_screen_and_the_script_form_apart():
    from payload_agent.output.pendant import pendant_values

    ur = pendant_values("ur_rtde", 2.0312, (30.33, -18.81, 60.44))
    assert ur.length_unit == "mm" and "PolyScope" in ur.screen  # PolyScope's payload screen: kg and mm
    assert "mass 2.031 kg, centre of gravity X 30.3 mm, Y -18.8 mm, Z 60.4 mm" in ur.describe()
    assert ur.script == "set_target_payload(2.031, [0.0303, -0.0188, 0.0604])"  # URScript: metres
    elite = pendant_values("elite_ec", 2.0312, (30.33, -18.81, 60.44))
    assert elite.length_unit == "mm" and '"cog": [30.3, -18.8, 60.4]' in elite.script
    generic = pendant_values("modbus", 2.0312, (30.33, -18.81, 60.44)).to_json()
    assert generic["cog_unit"] == "mm" and generic["script"] is None
