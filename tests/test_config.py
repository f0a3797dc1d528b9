"""Malformed robot YAML gets an error that names the key and what was expected."""

from pathlib import Path

import pytest

from conftest import DELETE, ROOT, tweak
from payload_agent.configuration.config import load_config, parse_config
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
    ("simulation.arm", "kuka", "simulation.arm", "ec66"),
]


@pytest.mark.parametrize("path,value,key,expect", CASES, ids=[c[0] + ":" + str(c[1])[:12] for c in CASES])
def test_malformed_config_names_the_key(sim_ec66_data, path, value, key, expect):
    with pytest.raises(ConfigError) as info:
        parse_config(tweak(sim_ec66_data, path, value), source="sim-ec66.yaml")
    message = str(info.value)
    assert info.value.key_path == key, message
    assert key in message and expect in message, message
    assert "sim-ec66.yaml" in message


def test_shipped_configs_load():
    for name in ("ec66.yaml", "sim-ec66.yaml"):
        cfg = load_config(ROOT / "configs" / name)
        assert cfg.robot.kinematics.n == 6
    real = load_config(ROOT / "configs" / "ec66.yaml")
    assert real.simulation is None and real.driver["host"] == "192.168.1.200"


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
