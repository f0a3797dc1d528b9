"""The inertia part of the procedure (procedures/wrist_inertia.yaml): planned, checked whole, refused by name."""

import math

import numpy as np
import pytest
import yaml

from conftest import DELETE, ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.configuration.wrist_procedure import parse_wrist_procedure
from payload_agent.errors import ConfigError
from payload_agent.motion.planner import make_plan, remaining_plan, turned_to
from payload_agent.motion.safety import SafetyGate

SIM = ROOT / "configs" / "sim-ec66.yaml"


def config(**changes):
    """The simulated EC66 without the inertia part and without a wrist speed cap, then ``changes``."""
    data = yaml.safe_load(SIM.read_text())
    data = tweak(tweak(data, "procedure.inertia", False), "safety.max_wrist_speed_percent", DELETE)
    for path, value in changes.items():
        data = tweak(data, path, value)
    return parse_config(data, source="sim-ec66.yaml")


def start(cfg):
    return np.radians(cfg.simulation.start_deg)


def test_the_wrist_moves_follow_the_sweeps_and_pass_the_gate_within_their_own_cap():
    cfg = config(**{"procedure.inertia": True, "safety.max_wrist_speed_percent": 100})
    plan = make_plan(cfg)
    wrist = plan.wrist_moves
    n = 2 * len(yaml.safe_load((ROOT / "procedures" / "wrist_inertia.yaml").read_text())["moves"])
    assert len(wrist) == n and len({m.wrist for m in wrist}) == n  # each move there and back
    assert plan.moves.index(wrist[0]) > plan.moves.index(plan.sweeps[-1])
    for m in wrist:  # the three wrist joints turn together, 45° each, at the procedure's speed and acceleration
        prev = np.asarray(plan.moves[plan.moves.index(m) - 1].target_rad)
        turned = np.abs(np.asarray(m.target_rad) - prev)
        assert np.allclose(turned, [0, 0, 0, math.radians(45), math.radians(45), math.radians(45)])
        assert m.speed_rad_s == pytest.approx(0.95 * cfg.robot.max_joint_speed_rad_s)
        assert m.accel_rad_s2 == pytest.approx(cfg.robot.max_joint_accel_rad_s2)
    assert all(np.max(np.abs(np.subtract(b.target_rad, a.target_rad))) > 0 for a, b in zip(plan.moves, plan.moves[1:]))
    verdict = SafetyGate(cfg).check(turned_to(cfg, plan, start(cfg)), start(cfg))  # as the run turns it
    assert verdict.ok, verdict.describe()
    # the plan's fingerprint (what a stored baseline depends on) changes with the inertia part
    assert plan.fingerprint() != make_plan(config()).fingerprint()
    # a resumed run redoes the wrist moves not yet recorded, after a move to the first one's start
    rest = remaining_plan(cfg, plan, {m.sweep.name for m in plan.sweeps} | {wrist[0].wrist})
    assert [m.wrist for m in rest.moves if m.kind == "wrist"] == [m.wrist for m in wrist[1:]]
    assert rest.moves[0].kind == "approach" and SafetyGate(cfg).check(rest, np.asarray(wrist[0].target_rad)).ok


def test_a_wrist_move_faster_than_the_yaml_allows_is_refused_by_name_not_slowed():
    cfg = config(**{"procedure.inertia": True})  # max_wrist_speed_percent defaults to max_speed_percent (25 %)
    plan = make_plan(cfg)
    assert plan.wrist_moves[0].speed_rad_s == pytest.approx(0.95 * cfg.robot.max_joint_speed_rad_s)  # not slowed
    verdict = SafetyGate(cfg).check(plan, start(cfg))
    assert not verdict.ok
    assert any("w1-c-j456 fwd" in p and "safety.max_wrist_speed_percent" in p for p in verdict.problems), verdict.problems


def test_a_wrist_move_past_a_joint_limit_is_refused_naming_it(tmp_path):
    data = yaml.safe_load((ROOT / "procedures" / "wrist_inertia.yaml").read_text())
    # joint 5 of pose c turned 660°: past the EC66's ±355° limits whichever whole turns the plan takes
    data["moves"][1]["range_deg"][1] = [-330, 330]
    path = tmp_path / "wrist_far.yaml"
    path.write_text(yaml.safe_dump(data))
    cfg = config(**{"procedure.inertia": str(path), "safety.max_wrist_speed_percent": 100})
    plan = make_plan(cfg)
    verdict = SafetyGate(cfg).check(plan, np.asarray(plan.moves[0].target_rad))
    assert not verdict.ok
    assert any("w2-c-j456 fwd" in p and "joint 5" in p and "outside limits" in p for p in verdict.problems), \
        verdict.problems


@pytest.mark.parametrize("path, value, words", [
    ("procedure.inertia", "wrist_nosuch", "no wrist procedure 'wrist_nosuch'"),
    ("procedure.inertia", 3, "expected true, false or a wrist procedure name"),
    ("safety.max_wrist_speed_percent", 130, "max_wrist_speed_percent"),
    ("safety.max_wrist_accel_deg_s2", 0, "max_wrist_accel_deg_s2"),
    ("safety.max_wrist_accel_deg_s2", "fast", "max_wrist_accel_deg_s2"),
])
def test_bad_inertia_keys_are_refused_with_their_key_path(path, value, words):
    with pytest.raises(ConfigError) as err:
        config(**{path: value})
    assert path in str(err.value) and words in str(err.value)


def test_a_wrist_procedure_file_is_checked_key_by_key():
    base = yaml.safe_load((ROOT / "procedures" / "wrist_inertia.yaml").read_text())
    bad = dict(base, moves=[{"pose": "c", "joint": 3, "range_deg": [0, 60]}])
    with pytest.raises(ConfigError, match=r"moves\[0\]\.joint"):
        parse_wrist_procedure(bad)
    bad = dict(base, moves=[{"pose": "c", "joint": 6, "range_deg": [0, 5]}])
    with pytest.raises(ConfigError, match=r"moves\[0\]\.range_deg: needs at least 20 degrees"):
        parse_wrist_procedure(bad)
    with pytest.raises(ConfigError, match="speed_pecent"):
        parse_wrist_procedure(dict(base, speed_pecent=50))
    # several joints turned together: one [from, to] per joint, each checked where it stands
    for move, where in [({"joint": [4, 4], "range_deg": [[0, 45], [0, 45]]}, r"moves\[0\]\.joint: .*different"),
                        ({"joint": [4, 7], "range_deg": [[0, 45], [0, 45]]}, r"moves\[0\]\.joint"),
                        ({"joint": [4, 5], "range_deg": [[0, 45]] * 3}, r"moves\[0\]\.range_deg: expected one \[from, to\]"),
                        ({"joint": [4, 5], "range_deg": [0, 45]}, r"moves\[0\]\.range_deg\[0\]: expected a list"),
                        ({"joint": [4, 5], "range_deg": [[0, 45], [0, 5]]},
                         r"moves\[0\]\.range_deg\[1\]: needs at least 20 degrees"),
                        ({"joint": [4, 5], "range_deg": [[0, 45], "far"]}, r"moves\[0\]\.range_deg\[1\]: expected a list")]:
        with pytest.raises(ConfigError, match=where):
            parse_wrist_procedure(dict(base, moves=[{"pose": "c", **move}]))
    one = parse_wrist_procedure(dict(base, moves=[{"pose": "c", "joint": 6, "range_deg": [0, 60]}])).moves[0]
    assert (one.joints, one.from_deg, one.to_deg, one.label) == ((6,), (0.0,), (60.0,), "j6")
    both = parse_wrist_procedure(dict(base, moves=[{"pose": "b", "joint": [5, 6], "range_deg": [[0, -45], [10, 55]]}]))
    assert both.moves[0].joints == (5, 6) and both.moves[0].to_deg == (-45.0, 55.0) and both.moves[0].label == "j56"


def test_a_one_joint_move_still_turns_that_joint_alone(tmp_path):
    data = yaml.safe_load((ROOT / "procedures" / "wrist_inertia.yaml").read_text())
    data["moves"] = [{"pose": "c", "joint": 6, "range_deg": [0, 60]}, {"pose": "b", "joint": [4, 5], "range_deg": [[0, 30], [0, -40]]}]
    path = tmp_path / "wrist_mixed.yaml"
    path.write_text(yaml.safe_dump(data))
    cfg = config(**{"procedure.inertia": str(path), "safety.max_wrist_speed_percent": 100})
    plan = make_plan(cfg)
    fwd = [m for m in plan.wrist_moves if m.label.endswith("fwd")]
    assert [m.label for m in fwd] == ["w1-c-j6 fwd", "w2-b-j45 fwd"]
    for m, turn in zip(fwd, ([0, 0, 0, 0, 0, 60], [0, 0, 0, 30, -40, 0])):
        prev = np.asarray(plan.moves[plan.moves.index(m) - 1].target_rad)
        assert np.allclose(np.degrees(np.asarray(m.target_rad) - prev), turn)
    assert SafetyGate(cfg).check(turned_to(cfg, plan, start(cfg)), start(cfg)).ok


UR = ROOT / "configs" / "sim-ur5e.yaml"


def ur_config(tmp_path, speed_percent: float, accel_deg_s2: float | None = None, **changes):
    """The simulated UR5e with the wrist moves at ``speed_percent`` of its 180 deg/s (cap 100 %) and, if given,
    ``accel_deg_s2`` (safety.max_wrist_accel_deg_s2: their 100 %), then ``changes``."""
    wrist = yaml.safe_load((ROOT / "procedures" / "wrist_inertia.yaml").read_text())
    wrist["speed_percent"] = speed_percent
    path = tmp_path / "wrist_fast.yaml"
    path.write_text(yaml.safe_dump(wrist))
    data = tweak(tweak(yaml.safe_load(UR.read_text()), "procedure.inertia", str(path)),
                 "safety.max_wrist_speed_percent", 100)
    if accel_deg_s2 is not None:
        data = tweak(data, "safety.max_wrist_accel_deg_s2", accel_deg_s2)
    for path, value in changes.items():
        data = tweak(data, path, value)
    return parse_config(data, source="sim-ur5e.yaml")


def test_a_move_faster_than_ur_rtde_moveJ_accepts_is_refused_by_the_plan_naming_move_and_limit(tmp_path):
    # 100 % of the UR5e's 180 deg/s is pi rad/s: within the YAML's caps, above the 3.14 rad/s ur-rtde's moveJ takes
    cfg = ur_config(tmp_path, 100)
    verdict = SafetyGate(cfg).check(turned_to(cfg, make_plan(cfg), start(cfg)), start(cfg))
    assert not verdict.ok
    wrist = [p for p in verdict.problems if "3.14 rad/s" in p]
    assert wrist and all("ur_rtde driver's move command" in p and "UR_JOINT_VELOCITY_MAX" in p for p in wrist)
    assert len(wrist) == len(make_plan(cfg).wrist_moves) and "move 13 (w1-c-j456 fwd)" in wrist[0]
    assert not [p for p in verdict.problems if p not in wrist and "approach" not in p]  # nothing else is wrong
    # the shipped 95 % passes the same check
    cfg = ur_config(tmp_path, 95)
    assert SafetyGate(cfg).check(turned_to(cfg, make_plan(cfg), start(cfg)), start(cfg)).ok


def test_an_acceleration_above_ur_rtde_moveJ_limit_is_refused_and_other_drivers_have_none(tmp_path):
    cfg = ur_config(tmp_path, 50, accel_deg_s2=3000)  # 52 rad/s² where ur-rtde's moveJ takes at most 40
    verdict = SafetyGate(cfg).check(turned_to(cfg, make_plan(cfg), start(cfg)), start(cfg))
    assert any("w1-c-j456 fwd" in p and "40 rad/s²" in p and "UR_JOINT_ACCELERATION_MAX" in p for p in verdict.problems)
    # the Elite EC driver declares no command limit of its own: the same speeds in rad/s pass its gate
    ec = config(**{"procedure.inertia": True, "safety.max_wrist_speed_percent": 100})
    assert type(ec.driver_options).command_limits.max_joint_speed_rad_s is None
    assert SafetyGate(ec).check(turned_to(ec, make_plan(ec), start(ec)), start(ec)).ok


def test_the_wrist_moves_take_the_yaml_wrist_acceleration_and_a_lower_cap_refuses_them_by_name(tmp_path):
    # the shipped sim-ur5e: safety.max_wrist_accel_deg_s2 286.5 (5 rad/s²) for the wrist moves only
    cfg = ur_config(tmp_path, 95)
    plan = turned_to(cfg, make_plan(cfg), start(cfg))
    assert plan.wrist_moves and all(m.accel_rad_s2 == pytest.approx(5.0, rel=1e-3) for m in plan.wrist_moves)
    rest = [m for m in plan.moves if m.kind != "wrist"]
    assert all(m.accel_rad_s2 <= cfg.robot.max_joint_accel_rad_s2 * (1 + 1e-9) for m in rest)
    assert SafetyGate(cfg).check(plan, start(cfg)).ok
    # the same plan under a YAML that allows the wrist less (edited between planning and running, say)
    low = ur_config(tmp_path, 95, 200)
    verdict = SafetyGate(low).check(plan, start(cfg))
    assert not verdict.ok
    named = [p for p in verdict.problems if "safety.max_wrist_accel_deg_s2" in p]
    assert len(named) == len(plan.wrist_moves) and "w1-c-j456 fwd" in named[0] and "286.5°/s²" in named[0], named
    assert len(verdict.problems) == len(named), verdict.problems  # nothing else is wrong
    # without the key the robot's acceleration is the wrist moves' 100 % and cap, and the refusal says so
    plain = ur_config(tmp_path, 95, **{"safety.max_wrist_accel_deg_s2": DELETE})
    assert make_plan(plain).wrist_moves[0].accel_rad_s2 == pytest.approx(plain.robot.max_joint_accel_rad_s2)
    verdict = SafetyGate(plain).check(plan, start(cfg))
    assert any("w1-c-j456 fwd" in p and "robot.max_joint_accel_deg_s2" in p for p in verdict.problems), verdict.problems


@pytest.mark.parametrize("name", ["ur5e.yaml", "ur10e.yaml"])
def test_the_real_ur_configs_carry_the_sourced_wrist_acceleration_and_leave_the_wrist_speed_to_the_user(name):
    data = tweak(yaml.safe_load((ROOT / "configs" / name).read_text()), "procedure.inertia", True)
    cfg = parse_config(data, source=name)
    assert cfg.wrist_accel_rad_s2 == pytest.approx(5.0, rel=1e-3)  # 286.5°/s², UR's ROS 2 driver
    plan = make_plan(cfg)
    begin = np.asarray(plan.moves[0].target_rad)
    assert all(m.accel_rad_s2 == pytest.approx(5.0, rel=1e-3) for m in plan.wrist_moves)
    verdict = SafetyGate(cfg).check(plan, begin)  # the wrist speed cap is still max_speed_percent: refused by name
    assert not verdict.ok and all("safety.max_wrist_speed_percent" in p for p in verdict.problems), verdict.problems
    fast = parse_config(tweak(data, "safety.max_wrist_speed_percent", 95), source=name)
    assert SafetyGate(fast).check(make_plan(fast), begin).ok
