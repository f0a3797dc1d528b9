"""Malformed robot YAML gets an error that names the file, the key and what was expected."""

import copy
import os
from pathlib import Path

import pytest
import yaml

from conftest import DELETE, ROOT, tweak
from payload_agent.configuration.config import load_config, parse_config
from payload_agent.configuration.paths import find_robot, state_home
from payload_agent.configuration.yamlcheck import load_yaml
from payload_agent.errors import ConfigError

CASES = [
    ("robot.name", DELETE, "robot.name", "required"),
    ("robot.kinematics.dh", [[0, 96, 90, 0]] * 6, "robot.kinematics.dh[0]", "mapping"),
    ("robot.kinematics.dh[1].a_mm", "418mm", "robot.kinematics.dh[1].a_mm", "number"),
    ("robot.kinematics.dh", [{"a_mm": 0, "d_mm": 1, "alpha_deg": 0}] * 5, "robot.kinematics.dh", "6 rows"),
    ("robot.kinematics.convention", "modified_dh", "robot.kinematics.convention", "standard_dh"),
    ("robot.joint_limits_deg[2]", [160, -160], "robot.joint_limits_deg[2]", "below max"),
    ("robot.max_joint_speed_deg_s", -5, "robot.max_joint_speed_deg_s", "> 0"),
    ("effort.unit", "volts", "effort.unit", "percent_rated"),
    ("effort.gains_nm_per_unit", [1.5, 1.5, 1.5], "effort.gains_nm_per_unit", "6 numbers"),
    ("driver.type", DELETE, "driver.type", "required"),
    ("procedure.speed_percent", 0, "procedure.speed_percent", "> 0"),
    ("procedure.speed_percent", 50, "procedure.speed_percent", "max_speed_percent"),
    ("procedure.sweep_deg", [0, 5], "procedure.sweep_deg", "10 degrees"),
    ("procedure.bidirectional", "yes", "procedure.bidirectional", "true or false"),
    ("procedure.solver", "magic", "procedure.solver", "three-step"),
    ("safety.floor_z_mm", DELETE, "safety.floor_z_mm", "required"),
    ("safety.reach_box_mm.z", [500, 0], "safety.reach_box_mm.z", "below max"),
    ("safety.approach_speed_pct", 5, "safety.approach_speed_pct", "unknown key"),
    ("safety.approach_speed_percent", 40, "safety.approach_speed_percent", "max_speed_percent"),
    ("simulation.payload.cog_mm", [1, 2], "simulation.payload.cog_mm", "3 numbers"),
    ("simulation.time_scale", "fast", "simulation.time_scale", "number"),
    # unit mistakes: the file and the key, and the unit the value looks like
    ("robot.kinematics.dh[0].alpha_deg", -1.5708, "robot.kinematics.dh[0].alpha_deg", "looks like radians"),
    ("robot.kinematics.dh[3].offset_deg", 3.14159, "robot.kinematics.dh[3].offset_deg", "looks like radians"),
    ("robot.joint_limits_deg", [[-6.2832, 6.2832]] * 6, "robot.joint_limits_deg[0]", "looks like radians"),
    ("robot.joint_limits_deg[1]", [-3.1416, 3.1416], "robot.joint_limits_deg[1]", "looks like radians"),
    ("robot.joint_limits_deg[0]", [-400, 400], "robot.joint_limits_deg[0]", "beyond ±360°"),
    # no silent default for a value that changes where the robot goes
    ("robot.kinematics.dh[2].offset_deg", DELETE, "robot.kinematics.dh[2].offset_deg", "is required"),
    # one acceleration setting
    ("driver.max_joint_accel_rad_s2", 6.0, "driver.max_joint_accel_rad_s2", "robot.max_joint_accel_deg_s2"),
]


@pytest.mark.parametrize("path,value,key,expect", CASES, ids=[c[0] + ":" + str(c[1])[:12] for c in CASES])
def test_malformed_config_names_the_key(sim_ec66_data, path, value, key, expect):
    with pytest.raises(ConfigError) as info:
        parse_config(tweak(sim_ec66_data, path, value), source="sim-ec66.yaml")
    message = str(info.value)
    assert info.value.key_path == key, message
    assert key in message and expect in message, message
    assert "sim-ec66.yaml" in message


def test_dh_in_metres_is_named(sim_ec66_data):
    rows = sim_ec66_data["robot"]["kinematics"]["dh"]
    metres = [dict(r, a_mm=r["a_mm"] / 1000, d_mm=r["d_mm"] / 1000) for r in rows]
    with pytest.raises(ConfigError) as info:
        parse_config(tweak(sim_ec66_data, "robot.kinematics.dh", metres), source="sim-ec66.yaml")
    assert info.value.key_path == "robot.kinematics.dh[1].a_mm"  # the longest length, 0.418
    assert "looks like metres" in str(info.value) and "write 418" in str(info.value)


@pytest.mark.parametrize("section,good,bad", [
    ("procedure", "speed_percent", "speed_percnt"),
    ("", "safety", "saftey"),
    ("robot.kinematics.dh[2]", "offset_deg", "ofset_deg"),
    ("safety", "floor_z_mm", "floor_mm"),
])
def test_misspelt_key_is_named_with_did_you_mean(sim_ec66_data, section, good, bad):
    data = copy.deepcopy(sim_ec66_data)
    node = data
    for part in [p for p in section.replace("]", "").replace("[", ".").split(".") if p]:
        node = node[int(part)] if isinstance(node, list) else node[part]
    node[bad] = node.pop(good)
    with pytest.raises(ConfigError) as info:
        parse_config(data, source="sim-ec66.yaml")
    assert info.value.key_path == (f"{section}.{bad}" if section else bad), str(info.value)
    assert f"did you mean {good!r}" in str(info.value)


def test_unknown_key_far_from_any_gets_the_list(sim_ec66_data):
    with pytest.raises(ConfigError, match=r"procedure.colour: unknown key; expected one of: accel_percent"):
        parse_config(tweak(sim_ec66_data, "procedure.colour", "red"), source="s.yaml")


def test_duplicate_keys_are_rejected_with_both_lines(tmp_path: Path):
    text = (ROOT / "configs" / "sim-ec66.yaml").read_text()
    assert "  speed_percent: 10" in text
    dup = text.replace("  speed_percent: 10", "  speed_percent: 10\n  speed_percent: 25", 1)
    path = tmp_path / "dup.yaml"
    path.write_text(dup)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.key_path == "procedure.speed_percent"
    assert "appears twice" in str(info.value) and str(path) in str(info.value)
    line = next(i for i, t in enumerate(dup.splitlines(), 1) if t.startswith("  speed_percent: 25"))
    assert f"and {line})" in str(info.value)
    with pytest.raises(ConfigError, match=r"robot.kinematics.dh\[0\].a_mm: appears twice"):
        load_yaml("robot:\n  kinematics:\n    dh:\n      - {a_mm: 0, a_mm: 1}\n", "f.yaml")


def test_shipped_configs_load_and_state_defaults_to_xdg():
    for name in ("ec66.yaml", "sim-ec66.yaml", "ur5e.yaml", "sim-ur5e.yaml"):
        cfg = load_config(ROOT / "configs" / name)
        assert cfg.robot.kinematics.n == 6
        assert cfg.storage.state_dir == state_home()
        assert cfg.storage.runs_dir == state_home() / cfg.robot.name / "runs"
    real = load_config(ROOT / "configs" / "ec66.yaml")
    assert real.simulation is None and real.driver["host"] == "192.168.1.200"
    assert str(state_home()).startswith(str(Path(os.environ["XDG_STATE_HOME"])))


def test_relative_paths_are_resolved_against_the_yaml_folder(sim_ec66_data, tmp_path: Path, monkeypatch):
    folder = tmp_path / "cell" / "robots"
    folder.mkdir(parents=True)
    data = tweak(tweak(sim_ec66_data, "storage.state_dir", "state"), "storage.runs_dir", "../runs")
    data = tweak(data, "watch.trigger.path", "flags/tool-changed")
    (folder / "r.yaml").write_text(yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path)  # elsewhere: the shell's directory must not matter
    cfg = load_config("cell/robots/r.yaml")
    assert cfg.storage.state_dir == folder / "state"
    assert cfg.storage.runs_dir.resolve() == (tmp_path / "cell" / "runs").resolve()
    assert cfg.watch.path == folder / "flags" / "tool-changed"


def test_robot_name_search_path(sim_ec66_data, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError) as info:
        find_robot("cellbot")
    assert "--robot" == info.value.key_path and "configs" in str(info.value) and "PAYLOAD_AGENT_ROBOTS" in str(info.value)
    extra = tmp_path / "extra"
    extra.mkdir()
    (extra / "cellbot.yaml").write_text(yaml.safe_dump(sim_ec66_data))
    monkeypatch.setenv("PAYLOAD_AGENT_ROBOTS", str(tmp_path / "nothing-here") + ":" + str(extra))
    assert find_robot("cellbot") == extra / "cellbot.yaml"
    xdg = Path(os.environ["XDG_CONFIG_HOME"]) / "payload-agent" / "robots"
    xdg.mkdir(parents=True, exist_ok=True)
    (xdg / "cellbot.yaml").write_text(yaml.safe_dump(sim_ec66_data))
    try:
        assert find_robot("cellbot") == xdg / "cellbot.yaml"  # XDG before PAYLOAD_AGENT_ROBOTS
        (tmp_path / "configs").mkdir()
        (tmp_path / "configs" / "cellbot.yaml").write_text(yaml.safe_dump(sim_ec66_data))
        assert find_robot("cellbot").resolve() == (tmp_path / "configs" / "cellbot.yaml").resolve()  # ./configs first
    finally:
        (xdg / "cellbot.yaml").unlink()
    assert find_robot(str(extra / "cellbot.yaml")) == extra / "cellbot.yaml"  # a path works as before
    with pytest.raises(ConfigError, match="no such file"):
        find_robot("some/where/else.yaml")


def test_invalid_yaml_and_missing_file(tmp_path: Path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: [unclosed\n")
    with pytest.raises(ConfigError, match=r"not valid YAML \(line"):
        load_config(bad)
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "nope.yaml")


def test_yaml_is_loaded_safely(tmp_path: Path):
    evil = tmp_path / "evil.yaml"
    evil.write_text("robot: !!python/object/apply:os.system ['echo hacked']\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(evil)


def test_mixed_unit_dh_table_names_the_rows_in_metres(sim_ec66_data):
    data = tweak(tweak(sim_ec66_data, "robot.kinematics.dh[1].a_mm", 0.418), "robot.kinematics.dh[2].a_mm", 0.398)
    with pytest.raises(ConfigError) as info:
        parse_config(data)
    text = str(info.value)
    assert info.value.key_path == "robot.kinematics.dh[1].a_mm"
    assert "robot.kinematics.dh[1].a_mm = 0.418 and robot.kinematics.dh[2].a_mm = 0.398 look like metres" in text
    assert "write 418, 398" in text
