"""The Python API identifies a payload without a subprocess, and fails with the documented errors."""

import pytest
import yaml

from conftest import ROOT
import payload_agent
from payload_agent.errors import BaselineError


def sim_robot(tmp_path, **sim):
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["driver"].update(rpc_port=0, monitor_port=0)
    data["simulation"].update(sim)
    data["storage"] = {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")}
    data.pop("watch", None)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_identify_returns_the_result(tmp_path):
    robot = sim_robot(tmp_path, payload={"mass_kg": 1.4, "cog_mm": [20, 30, 90]})
    result = payload_agent.identify(str(robot), unattended=True, fresh_baseline=True)
    assert abs(result.primary.mass_kg - 1.4) < 0.03
    assert max(abs(a - b) for a, b in zip(result.primary.cog_mm, (20, 30, 90))) < 5.0
    assert result.quality["passed"]


def test_unattended_identify_without_a_baseline_raises_the_documented_error(tmp_path):
    with pytest.raises(BaselineError) as err:
        payload_agent.identify(str(sim_robot(tmp_path)), unattended=True)
    assert err.value.exit_code == 3
