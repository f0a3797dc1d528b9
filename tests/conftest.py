import copy
import math
import os
import tempfile
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]

# State follows the robot into $XDG_STATE_HOME (payload_agent.configuration.paths): the suite gets its
# own, so it never reads or writes the user's baselines, calibrations or history (subprocesses inherit it).
_XDG = Path(tempfile.mkdtemp(prefix="payload-agent-tests-"))
os.environ["XDG_STATE_HOME"] = str(_XDG / "state")
os.environ["XDG_CONFIG_HOME"] = str(_XDG / "config")
os.environ.pop("PAYLOAD_AGENT_ROBOTS", None)


@pytest.fixture
def sim_ec66_data():
    """The simulated EC66 config as a dict, to be tweaked per test; without the inertia part (its wrist moves
    double a session's moves: tests/test_wrist_*.py turn it on)."""
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["procedure"]["inertia"] = False
    return data


@pytest.fixture
def ec66_data():
    return yaml.safe_load((ROOT / "configs" / "ec66.yaml").read_text())


def tweak(data, path, value):
    """Return a deep copy with ``path`` ("a.b[2].c") set to value; value=DELETE removes the key."""
    data = copy.deepcopy(data)
    node = data
    parts = path.replace("]", "").replace("[", ".").split(".")
    for p in parts[:-1]:
        node = node[int(p)] if isinstance(node, list) else node[p]
    last = parts[-1]
    if value is DELETE:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return data


DELETE = object()

EC66_Q0 = [0.0, -math.pi / 2, math.pi / 2, 0.0, math.pi / 2, 0.0]  # the fakes' tests start the EC66 here
EC66_TIME_SCALE = 40.0


@pytest.fixture
def ec66_sim():
    """A running simulated EC66 (no payload) at EC66_Q0, 40x faster than wall time; closed afterwards."""
    from payload_agent.fakes.arms import ec66_spec
    from payload_agent.fakes.sim_robot import SimRobot

    robot = SimRobot(ec66_spec(), q0_rad=EC66_Q0, tick_s=0.008, time_scale=EC66_TIME_SCALE)
    robot.start()
    yield robot
    robot.close()
