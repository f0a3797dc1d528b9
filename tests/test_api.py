"""The Python API identifies a payload without a subprocess, and fails with the documented errors.

``payload_agent.identify`` is a thin wrapper over the session (find and load the robot YAML, run, return the
result): it is tested here with the in-process driver of tests/inproc_driver.py, whose session costs a third
of a simulated EC66's over sockets; the protocols themselves are the end-to-end tests' business.
"""

import pytest
import yaml

from conftest import ROOT, fast_start
from inproc_driver import InProcessDriver
import payload_agent
from payload_agent.drivers import registry
from payload_agent.errors import BaselineError

registry.register("inproc", InProcessDriver)


def sim_robot(tmp_path, **sim):
    """A robot YAML file: the simulated EC66 cell, its controller the in-process one."""
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["driver"] = {"type": "inproc", "name": f"api-{tmp_path.name}"}
    data["effort"] = {"unit": "Nm", "gains_nm_per_unit": 1.0}
    data["procedure"]["inertia"] = False
    data["procedure"]["name"] = "j2_pair"  # two sweeps, not four: the wrapper is tested, not the procedure
    data["safety"]["unattended_without_pose_check"] = True  # it reports no flange pose (the YAML acknowledges)
    data["simulation"].update(sim)
    data["storage"] = {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")}
    data.pop("watch", None)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(fast_start(data)))  # nor the approach (conftest.fast_start)
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
