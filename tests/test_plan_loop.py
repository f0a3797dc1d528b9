"""A run may start where the last one ended: the loaded run where the empty run ended, the next session where
this one left the arm. Every shipped plan must therefore "close its loop": from its own end pose (the plan turned
to it, as a session turns it) the safety gate finds nothing it would not find from the plan's own start. And a
session that records two runs checks the second from where the first ends before the first move: a plan that
cannot close is refused whole, not after the empty run has moved.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from conftest import ROOT, fast_start, tweak
from payload_agent.configuration.config import load_config, parse_config
from payload_agent.errors import SafetyError
from payload_agent.motion.planner import MAX_SINGLE_MOVE_RAD, make_plan, remaining_plan, turned_to
from payload_agent.motion.safety import SafetyGate
from payload_agent.output.plan_table import loop_sentence
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification
from payload_agent.session.simulation import SimulatedCell

CONFIGS = sorted(p.name for p in (ROOT / "configs").glob("*.yaml"))
PROCEDURES = sorted(p.stem for p in (ROOT / "procedures").glob("*.yaml") if not p.stem.startswith("wrist_"))


def _config(config_name: str, procedure: str, inertia: bool):
    cfg = load_config(ROOT / "configs" / config_name)
    return dataclasses.replace(cfg, procedure=dataclasses.replace(
        cfg.procedure, name=procedure, inertia="wrist_inertia" if inertia else None))


@pytest.mark.parametrize("inertia", [False, True], ids=["sweeps", "inertia"])
@pytest.mark.parametrize("procedure", PROCEDURES)
@pytest.mark.parametrize("config_name", CONFIGS)
def test_every_shipped_plan_passes_the_gate_from_its_own_end_pose(config_name, procedure, inertia):
    cfg = _config(config_name, procedure, inertia)
    plan = make_plan(cfg)
    gate = SafetyGate(cfg)
    first, end = np.asarray(plan.moves[0].target_rad), np.asarray(plan.moves[-1].target_rad)
    # what the gate says anyway (some robots' caps refuse the inertia part's speed: not this test's subject)
    anyway = set(gate.check(plan, first).problems)
    for start in (turned_to(cfg, plan, end), plan):  # the next session turns it; a session's second run does not
        added = [p for p in gate.check(start, end).problems if p not in anyway]
        assert not added, f"{config_name} {procedure} inertia={inertia}: from its own end pose: {added}"
    assert np.max(np.abs(end - first)) <= MAX_SINGLE_MOVE_RAD
    assert gate.check_loop(plan).ok
    assert loop_sentence(gate.check_loop(plan)).startswith("the plan closes its loop")


def test_a_plan_that_could_not_close_ends_with_one_travel_to_a_pose_it_already_stood_in():
    """j2_quarter with the inertia part on sim-ur5e: no whole turns of the wrist close it (joint 6 steps 90° the
    same way at each of its four orientations), so it ends with a travel move, within one move of its end and of
    its start; the recorded moves are those of the plan without it."""
    cfg = _config("sim-ur5e.yaml", "j2_quarter", True)
    plan = make_plan(cfg)
    last, before = plan.moves[-1], plan.moves[-2]
    assert last.kind == "travel" and last.recorded_name is None and before.kind == "wrist"
    assert last.target_rad in [m.target_rad for m in plan.moves[:-1]]
    assert np.max(np.abs(np.subtract(last.target_rad, before.target_rad))) <= MAX_SINGLE_MOVE_RAD
    assert np.max(np.abs(np.subtract(last.target_rad, plan.moves[0].target_rad))) <= MAX_SINGLE_MOVE_RAD
    # a resumed run (and redone empty sweeps) ends there too, so the run after it starts where it was checked from
    rest = remaining_plan(cfg, plan, {m.sweep.name for m in plan.sweeps})
    assert rest.moves[-1].target_rad == last.target_rad


def _unclosable_procedure(path) -> str:
    """Four joint-2 orientations whose wrist chain winds joint 6 270° one way: no visited pose lies within one
    move of both the plan's end and its start, so nothing the planner may do closes it."""
    path.write_text(yaml.safe_dump({
        "name": "winding", "description": "four orientations that wind joint 6",
        "poses": {"p0": {"tool_x": "-arm", "tool_z": "axis"}, "p1": {"tool_x": "up", "tool_z": "-arm"},
                  "p2": {"tool_x": "-up", "tool_z": "axis"}, "p3": {"tool_x": "-up", "tool_z": "-axis"}},
        "sweeps": [{"pose": f"p{i}", "joint": 2} for i in range(4)]}))
    return str(path)


def test_plan_says_a_plan_does_not_close_and_why(sim_ec66_data, tmp_path):
    cfg = parse_config(tweak(sim_ec66_data, "procedure.name", _unclosable_procedure(tmp_path / "winding.yaml")),
                       "sim-ec66.yaml")
    plan = make_plan(cfg)
    gate = SafetyGate(cfg)
    assert gate.check(plan, np.asarray(plan.moves[0].target_rad)).ok  # the plan itself is fine
    loop = gate.check_loop(plan)
    assert not loop.ok and any("joint 6 turns 270°" in p and "move 1 (approach" in p for p in loop.problems)
    assert loop_sentence(loop).startswith("the plan does NOT close its loop") and "joint 6" in loop_sentence(loop)


def test_a_session_whose_loaded_run_cannot_start_where_the_empty_run_ends_is_refused_before_moving(
        sim_ec66_data, tmp_path, monkeypatch):
    monkeypatch.setattr("builtins.input", lambda prompt: pytest.fail(f"asked {prompt!r} after the refusal"))
    data = tweak(sim_ec66_data, "procedure.name", _unclosable_procedure(tmp_path / "winding.yaml"))
    data = tweak(data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "robot.name", "loop-check")
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    config = parse_config(fast_start(data), str(tmp_path / "loop-check.yaml"))  # the arm stands at the first move
    cell = SimulatedCell(config).start()
    try:
        moves_before = cell.robot.snapshot().move_id
        said: list[str] = []
        with pytest.raises(SafetyError) as refused:
            run_identification(config, RunOptions(assume_yes=True, report=False),
                               OperatorUI(out=said.append, progress=False), SimulatedCellUse(cell=cell))
        assert cell.robot.snapshot().move_id == moves_before, "the simulated robot was commanded to move"
    finally:
        cell.close()
    text = str(refused.value)
    assert "before its first move" in text and "the loaded run starts where the empty-flange run ends" in text
    assert "joint 6 turns 270°" in text and "payload-agent baseline" in text  # the joint and the remedy
    assert any(line.startswith("Safety gate: SAFE") for line in said)  # the first run alone would have passed
    runs = tmp_path / "runs"
    assert not runs.exists() or not any(runs.iterdir()), "a run folder was opened for a session that never moved"


def test_the_next_session_leaves_our_own_resting_pose_at_travel_speed_and_only_from_there(sim_ec66_data, tmp_path):
    """A session that starts where our own last completed motion left the arm (the record in the state folder,
    matching the live angles) makes its first move at travel speed, says so, and the gate approves it; once the
    arm was moved by someone else, the next session approaches slowly again (issue 22 item 3, as `verify` does
    since issue 23)."""
    import math

    from conftest import cell_program_turns_joint_1, short_session
    from payload_agent.recording import resting_pose
    from payload_agent.recording.rundata import load_manifest
    from payload_agent.recording.state import RobotState

    data = tweak(sim_ec66_data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "robot.name", "from-rest")
    data = tweak(data, "procedure.inertia", False)
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    config = parse_config(short_session(data), str(tmp_path / "from-rest.yaml"))
    vmax = config.robot.max_joint_speed_rad_s
    cell = SimulatedCell(config).start()

    def session() -> tuple[float, str]:
        said: list[str] = []
        outcome = run_identification(config, RunOptions(mode="baseline", assume_yes=True, report=False),
                                     OperatorUI(out=said.append, progress=False), SimulatedCellUse(cell=cell))
        first = load_manifest(outcome.run_dir)["first_move"]
        return 100 * math.radians(first["speed_deg_s"]) / vmax, "\n".join(said)

    try:
        pct, text = session()  # no record yet: the approach speed
        assert pct == pytest.approx(config.safety.approach_speed_percent) and "travel speed" not in text
        assert resting_pose.standing_at(RobotState.for_config(config).root, cell.robot.snapshot().q) is not None
        pct, text = session()
        assert config.procedure.travel_speed_percent > config.safety.approach_speed_percent
        assert pct == pytest.approx(config.procedure.travel_speed_percent)
        assert "first move runs at travel speed" in text and "Safety gate: SAFE" in text
        cell_program_turns_joint_1(cell, 2.0)  # someone else moved the arm: the record no longer matches
        pct, text = session()
        assert pct == pytest.approx(config.safety.approach_speed_percent) and "travel speed" not in text
    finally:
        cell.close()
