"""The planner puts the links where the paper's procedure says; the gate refuses unsafe plans."""

import dataclasses
import math

import numpy as np
import pytest

from conftest import tweak
from payload_agent.model.arm_geometry import ArmGeometry
from payload_agent.configuration.config import parse_config
from payload_agent.errors import SafetyError
from payload_agent.motion.planner import make_plan, turned_to
from payload_agent.motion.safety import SafetyGate


def test_sweeps_follow_the_paper(sim_ec66_data):
    cfg = parse_config(tweak(sim_ec66_data, "procedure.bidirectional", False))  # as published: one way
    plan = make_plan(cfg)
    kin = cfg.robot.kinematics
    geo = ArmGeometry(kin, 0.0)
    sweeps = plan.sweeps
    assert [m.sweep.name for m in sweeps] == ["b-j2-up", "b-j3-up", "d-j2-up", "d-j3-up"]
    for m in sweeps:
        q = np.asarray(m.target_rad)
        e2, e3 = geo.elevations(q[1], q[2])
        if m.sweep.joint == 2:  # links collinear, raised to 55°
            assert math.degrees(e2) == pytest.approx(55) and math.degrees(e3) == pytest.approx(55)
        else:  # link 2 vertical, link 3 raised to 55°
            assert math.degrees(e2) == pytest.approx(90) and math.degrees(e3) == pytest.approx(55)
        R = kin.flange(q)[:3, :3]
        arm = geo.arm_frame(q)
        if m.sweep.pose == "b":  # tool x along the arm, tool z along the joint axes
            assert R[:, 0] @ arm["arm"] == pytest.approx(1) and abs(R[:, 2] @ arm["axis"]) == pytest.approx(1)
        else:  # tool z along the arm
            assert R[:, 2] @ arm["arm"] == pytest.approx(1)


def test_bidirectional_adds_return_sweeps(sim_ec66_data):
    cfg = parse_config(tweak(sim_ec66_data, "procedure.bidirectional", True))
    names = [m.sweep.name for m in make_plan(cfg).sweeps]
    assert names == ["b-j2-up", "b-j2-down", "b-j3-up", "b-j3-down", "d-j2-up", "d-j2-down", "d-j3-up", "d-j3-down"]


def test_gate_accepts_the_shipped_plan(sim_ec66_data):
    cfg = parse_config(sim_ec66_data)
    start = np.radians(cfg.simulation.start_deg)
    verdict = SafetyGate(cfg).check(turned_to(cfg, make_plan(cfg), start), start)  # as the run has it
    assert verdict.ok, verdict.describe()


@pytest.mark.parametrize("path,value,problem", [
    ("safety.floor_z_mm", 400, "below the floor"),
    ("safety.reach_box_mm.x", [-1000, 500], "reach box"),
    ("robot.joint_limits_deg[1]", [-50, 50], "outside limits"),
])
def test_gate_refuses(sim_ec66_data, path, value, problem):
    cfg = parse_config(tweak(sim_ec66_data, path, value))
    gate = SafetyGate(cfg)
    plan = make_plan(cfg)
    start = np.radians(cfg.simulation.start_deg)
    assert not gate.check(plan, start).ok
    with pytest.raises(SafetyError, match=problem):
        gate.approve(plan, start)


def test_the_tool_sphere_is_kept_above_the_floor_where_the_flange_alone_would_pass(sim_ec66_data):
    """safety.tool_radius_mm: a tool reaches below its flange. With the floor 50 mm under the plan's lowest flange
    point, the flange passes, a 100 mm tool does not, and the refusal names the tool; without the key the gate
    says that it checked the flange only."""
    cfg = parse_config(tweak(sim_ec66_data, "safety.tool_radius_mm", 0))
    start = np.radians(cfg.simulation.start_deg)
    plan = turned_to(cfg, make_plan(cfg), start)
    qs = [start] + [np.asarray(m.target_rad) for m in plan.moves]
    lowest = min(cfg.robot.kinematics.flange(a + (b - a) * k / 60)[2, 3] for a, b in zip(qs, qs[1:])
                 for k in range(61))
    floor = round(1000 * lowest) - 50
    data = tweak(sim_ec66_data, "safety.floor_z_mm", floor)
    flange_only = data["safety"].copy()
    del flange_only["tool_radius_mm"]
    verdict = SafetyGate(parse_config(tweak(data, "safety", flange_only))).check(plan, start)
    assert verdict.ok and "the tool not checked: no safety.tool_radius_mm" in verdict.describe()
    tool = parse_config(tweak(data, "safety.tool_radius_mm", 100))
    with pytest.raises(SafetyError, match=rf"tool \(within 100 mm of the flange\) at z = -?\d+ mm \(flange at "
                                          rf"\d+ mm\), below the floor \({floor} mm\)"):
        SafetyGate(tool).approve(plan, start)


def test_the_path_check_finds_the_first_point_out_of_bounds_as_one_pose_at_a_time_does(sim_ec66_data):
    """``workspace.outside_on_path`` takes the flange positions of a whole path in one batch (the gate's and the
    plan's cost): on every move of the shipped plan, with a floor and a box that cut the paths at different points,
    it names the same point as ``outside`` on one ``Kinematics.flange`` at a time, and the batch's positions are
    those poses' to 1e-12 m."""
    from payload_agent.motion import workspace

    cfg = parse_config(sim_ec66_data)
    start = np.radians(cfg.simulation.start_deg)
    plan = turned_to(cfg, make_plan(cfg), start)
    kin, n = cfg.robot.kinematics, workspace.PATH_CHECK_POINTS
    qs = [start] + [np.asarray(m.target_rad) for m in plan.moves]
    paths = list(zip(qs, qs[1:]))
    one_by_one = [[kin.flange(a + (b - a) * k / n)[:3, 3] for k in range(n + 1)] for a, b in paths]
    for (a, b), xyz in zip(paths, one_by_one):
        batch = kin.frames(a + (b - a) * np.arange(n + 1.0)[:, None] / n)[-1][:, :3, 3]
        assert np.allclose(batch, xyz, rtol=0.0, atol=1e-12)
    z = np.array([p[2] for xyz in one_by_one for p in xyz])
    x = np.array([p[0] for xyz in one_by_one for p in xyz])
    cuts = [("safety.floor_z_mm", float(np.round(1000 * q, 3))) for q in np.quantile(z, (0.1, 0.5, 0.9))]
    cuts += [("safety.reach_box_mm.x", [float(np.round(1000 * q, 3)), 2000.0]) for q in np.quantile(x, (0.2, 0.7))]
    found = 0
    for key, value in cuts:
        s = parse_config(tweak(sim_ec66_data, key, value)).safety
        for (a, b), xyz in zip(paths, one_by_one):
            expected = next((out for out in (workspace.outside(s, p) for p in xyz) if out is not None), None)
            assert workspace.outside_on_path(s, kin, a, b) == expected
            found += expected is not None
    assert found > 10  # the cuts do cut


def test_gate_refuses_unknown_start_and_fast_approach(sim_ec66_data):
    cfg = parse_config(sim_ec66_data)
    plan = make_plan(cfg)
    assert any("current joint angles unknown" in p for p in SafetyGate(cfg).check(plan, None).problems)
    first = plan.moves[0]
    fast = dataclasses.replace(plan, moves=(dataclasses.replace(first, speed_rad_s=first.speed_rad_s * 2),
                                            *plan.moves[1:]))
    problems = SafetyGate(cfg).check(fast, np.radians(cfg.simulation.start_deg)).problems
    assert any("approach cap" in p for p in problems)


class _RecordingDriver:
    def __init__(self):
        self.moves = []

    def move_joints(self, target, speed, accel, timeout_s):
        self.moves.append(tuple(target))


def test_gate_executes_only_the_next_approved_move(sim_ec66_data):
    cfg = parse_config(sim_ec66_data)
    start = np.radians(cfg.simulation.start_deg)
    plan = turned_to(cfg, make_plan(cfg), start)
    gate = SafetyGate(cfg)
    driver = _RecordingDriver()
    with pytest.raises(SafetyError, match="no approved plan"):
        gate.execute(driver, plan.moves[0], start)
    gate.approve(plan, start)
    with pytest.raises(SafetyError, match="not the next approved move"):
        gate.execute(driver, plan.moves[1], start)
    with pytest.raises(SafetyError, match="away from where"):
        gate.execute(driver, plan.moves[0], start + 0.1)
    gate.execute(driver, plan.moves[0], start)
    assert driver.moves == [plan.moves[0].target_rad]


@pytest.mark.parametrize("config", ["sim-ec66", "sim-ur5e"])
def test_the_wrist_solution_gives_every_orientation_asked_for(config):
    """Closed-form joints 4-6 for random tool orientations and arm poses, the wrist-singular ones included
    (tool z along link 3's joint axes lines joints 4 and 6 up on these arms)."""
    from conftest import ROOT
    from payload_agent.configuration.config import load_config

    cfg = load_config(ROOT / "configs" / f"{config}.yaml")
    kin = cfg.robot.kinematics
    geo = ArmGeometry(kin, 0.0)
    limits = [(-2 * math.pi, 2 * math.pi)] * 3
    rng = np.random.default_rng(7)
    for k in range(40):
        q2, q3 = rng.uniform(-math.pi, math.pi, 2)
        if k % 4 == 0:  # singular: the orientation of a wrist with joint 5 at 0 or 180°
            w = np.array([rng.uniform(-3, 3), math.pi * (k % 8 == 0), rng.uniform(-3, 3)])
        else:
            w = rng.uniform(-math.pi, math.pi, 3)
        R = kin.flange(np.array([0.0, q2, q3, *w]))[:3, :3]
        got = geo.wrist_for(q2, q3, R, limits, prefer=rng.uniform(-1, 1, 3))
        assert np.max(np.abs(kin.flange(np.array([0.0, q2, q3, *got]))[:3, :3] - R)) < 1e-5  # the angles are rounded to 1e-4°


@pytest.mark.parametrize("j4_start_deg", [90.0, -90.0])
def test_a_wrist_at_180_degrees_is_reached_the_short_way_and_the_plan_stays_the_same(sim_ec66_data, j4_start_deg):
    """±180° on a wrist joint is one pose: the run turns the whole plan by whole turns towards where the arm
    stands (the gate refuses a 270° approach), and the stored baseline still matches (same fingerprint)."""
    cfg = parse_config(tweak(sim_ec66_data, "procedure.name", "j2_triple"))
    plan = make_plan(cfg)
    start = np.radians([0.0, -90.0, 90.0, j4_start_deg, -90.0, 0.0])
    turned = turned_to(cfg, plan, start)
    first = np.degrees(turned.moves[0].target_rad)
    assert max(abs(first[3:] - np.degrees(start[3:]))) <= 180.0 + 1e-6
    assert turned.fingerprint() == plan.fingerprint()
    steps = np.degrees(np.diff([m.target_rad for m in turned.moves], axis=0))
    assert np.allclose(steps, np.degrees(np.diff([m.target_rad for m in plan.moves], axis=0)))  # same moves
    assert SafetyGate(cfg).check(turned, start).ok, SafetyGate(cfg).check(turned, start).describe()
    assert make_plan(cfg).fingerprint() == plan.fingerprint()  # the plan itself does not depend on the start


def test_first_move_at_travel_speed_only_from_our_own_matching_resting_pose(sim_ec66_data, tmp_path):
    """Issue 23: a verify may leave the arm's resting pose at travel speed, only when the live angles match the
    record our last completed phase wrote; otherwise the approach cap holds. The record survives a round trip,
    and an unreadable one counts as none (the slow approach)."""
    from payload_agent.recording import resting_pose

    cfg = parse_config(sim_ec66_data)
    start = np.radians(cfg.simulation.start_deg)
    plan = turned_to(cfg, make_plan(cfg), start)  # as the run has it
    vmax = cfg.robot.max_joint_speed_rad_s
    travel = vmax * cfg.procedure.travel_speed_percent / 100.0
    assert travel > vmax * cfg.safety.approach_speed_percent / 100.0
    first = dataclasses.replace(plan.moves[0], speed_rad_s=travel)
    fast = dataclasses.replace(plan, moves=(first, *plan.moves[1:]))
    assert resting_pose.load(tmp_path) is None
    rec = resting_pose.record(tmp_path, start, tmp_path / "run-1")
    assert resting_pose.load(tmp_path) == rec
    assert not SafetyGate(cfg).check(fast, start).ok  # no record given: the approach cap
    assert SafetyGate(cfg, rec).check(fast, start).ok  # standing where our run left it
    moved = start + np.radians([0, 0.5, 0, 0, 0, 0])  # someone moved joint 2 by half a degree
    problems = SafetyGate(cfg, rec).check(fast, moved).problems
    assert any("0.50° from the recorded resting pose" in p for p in problems), problems
    too_fast = dataclasses.replace(plan, moves=(dataclasses.replace(first, speed_rad_s=travel * 1.5),
                                                *plan.moves[1:]))
    assert any("travel speed from our own resting pose" in p for p in SafetyGate(cfg, rec).check(too_fast, start).problems)
    resting_pose.clear(tmp_path)
    assert resting_pose.load(tmp_path) is None
    resting_pose.path_for(tmp_path).write_text("{not json")
    assert resting_pose.load(tmp_path) is None


def test_a_resting_path_matches_only_angles_on_that_path(sim_ec66_data, tmp_path):
    """After a stop of our own supervision the record is the path of the move under way: angles on the straight
    joint-space line match it (the gate then allows travel speed), angles off it or past its ends do not."""
    from payload_agent.recording import resting_pose

    a, b = np.radians([0, -30, 60, 0, 90, 0]), np.radians([0, -50, 80, 0, 90, 40])
    rec = resting_pose.record(tmp_path, a, tmp_path / "run-2", q_to=b)
    assert resting_pose.load(tmp_path) == rec and "on the path" in rec.describe()
    assert rec.matches(a) and rec.matches(b) and rec.matches(a + 0.37 * (b - a))
    assert not rec.matches(a + 0.37 * (b - a) + np.radians([0, 0, 0, 0.3, 0, 0]))  # off the line
    assert not rec.matches(b + 0.05 * (b - a))  # beyond where the move was going
    cfg = parse_config(sim_ec66_data)
    plan = make_plan(cfg)
    travel = cfg.robot.max_joint_speed_rad_s * cfg.procedure.travel_speed_percent / 100.0
    fast = dataclasses.replace(plan, moves=(dataclasses.replace(plan.moves[0], speed_rad_s=travel), *plan.moves[1:]))
    mid = a + 0.5 * (b - a)
    on_path = SafetyGate(cfg, rec).check(fast, mid).problems
    assert not any("approach cap" in p for p in on_path)  # travel speed allowed from the stopped move's path
    assert any("approach cap" in p for p in SafetyGate(cfg, rec).check(fast, mid + np.radians(1.0)).problems)
