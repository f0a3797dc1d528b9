"""``--robot`` finds the shipped robot files from any directory, and a miss says where it looked."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

from conftest import ROOT
from payload_agent.configuration.paths import find_robot, robot_search_path, shipped_robot_dirs
from payload_agent.errors import ConfigError


def test_shipped_robots_found_from_any_directory(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./configs here
    found = find_robot("sim-ec66")
    assert found.resolve() == (ROOT / "configs" / "sim-ec66.yaml").resolve()
    assert find_robot("sim-ec66.yaml").resolve() == found.resolve()  # the file name works too
    assert robot_search_path()[-1].resolve() == (ROOT / "configs").resolve()  # shipped ones come last


def test_file_name_tries_configs_first(sim_ec66_data, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "sim-ec66.yaml").write_text(yaml.safe_dump(sim_ec66_data))
    assert find_robot("sim-ec66.yaml").resolve() == (tmp_path / "configs" / "sim-ec66.yaml").resolve()


def test_a_folder_is_a_clear_error(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cell").mkdir()
    with pytest.raises(ConfigError, match="is a folder, not a robot YAML file") as info:
        find_robot("cell")
    assert info.value.key_path == "--robot"


def test_a_miss_lists_every_place_looked(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    extra = tmp_path / "extra"
    monkeypatch.setenv("PAYLOAD_AGENT_ROBOTS", str(extra))
    with pytest.raises(ConfigError) as info:
        find_robot("cellbot.yaml")
    text = str(info.value)
    for place in [tmp_path / "cellbot.yaml", tmp_path / "configs" / "cellbot.yaml",
                  Path(os.environ["XDG_CONFIG_HOME"]) / "payload-agent" / "robots" / "cellbot.yaml",
                  extra / "cellbot.yaml", shipped_robot_dirs()[0] / "cellbot.yaml"]:
        assert str(place) in text, place


def test_python_api_uses_the_same_lookup(tmp_path: Path, monkeypatch):
    import payload_agent

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match="looked in: .*configs"):
        payload_agent.identify("no-such-robot")


def test_cli_plan_from_elsewhere(tmp_path: Path):
    proc = subprocess.run([sys.executable, "-m", "payload_agent.cli", "plan", "--robot", "sim-ec66"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_robot_files_and_presets_are_package_data():
    """A wheel carries the shipped robots and the Modbus presets as proper (data-only) packages."""
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert tool["package-dir"]["payload_agent.configs"] == "configs"
    assert {"payload_agent.configs", "payload_agent.drivers.modbus.presets"} <= set(tool["packages"])
    assert tool["package-data"]["payload_agent.configs"] == ["*.yaml"]
    assert tool["package-data"]["payload_agent.drivers.modbus.presets"] == ["*.yaml"]


def test_readme_sample_rates_match_the_simulation_configs():
    """The README's CANopen row says what the simulation streams: SYNC rate in wall time, divided by the time scale."""
    readme = (ROOT / "README.md").read_text()
    sim = yaml.safe_load((ROOT / "configs" / "sim-canopen-arm.yaml").read_text())
    sync, scale = sim["driver"]["sync_rate_hz"], sim["simulation"]["time_scale"]
    row = next(line for line in readme.splitlines() if line.startswith("| `configs/sim-canopen-arm.yaml`"))
    assert f"{sync:g} Hz SYNC in wall time = {sync / scale:g} per simulated second" in row
    assert f"`time_scale` {scale:g}" in row
