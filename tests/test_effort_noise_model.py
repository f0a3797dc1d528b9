"""The simulated drives' effort noise follows the robot YAML per joint, standing and moving.

- ``simulation.noise_rest_nm`` (a standing joint) and ``simulation.noise_nm`` (a moving one) arrive in the
  SimRobot a simulated controller builds, and the reported torque's scatter around the noise-free torque
  has those standard deviations: joints 1-3 and 5 stand while joints 4 and 6 turn (what the wrist moves of
  the inertia part do);
- without ``noise_rest_nm`` a standing joint is as noisy as a moving one (configs without a basis for it);
- a wrong ``noise_rest_nm`` is refused naming the key.
"""

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.errors import ConfigError
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.base import sim_robot_kwargs
from payload_agent.fakes.sim_robot import NOISE_RAMP_RAD_S, SimRobot

from conftest import ROOT, tweak

MOVING = (3, 5)  # joints 4 and 6 (0-based)
TICKS = 3000


def _ur5e_data() -> dict:
    return yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text())


def _scatter(config) -> tuple[np.ndarray, np.ndarray]:
    """σ of the reported torque minus the noise-free torque, per joint, standing and moving (NaN: no samples)."""
    kw = sim_robot_kwargs(config)
    spec = SPECS[config.simulation.arm]
    noisy = SimRobot(spec(), tick_s=0.002, **kw)
    clean = SimRobot(spec(), tick_s=0.002, **{**kw, "noise_nm": 0.0, "noise_rest_nm": 0.0})
    target = np.asarray(kw["q0_rad"], float).copy()
    target[list(MOVING)] += np.radians(90.0)
    for r in (noisy, clean):
        r.move_joints(target, speed_rad_s=1.0, accel_rad_s2=2.0)
    diff, speed = [], []
    for _ in range(TICKS):
        a, b = noisy.step(), clean.step()
        diff.append(a.torque_nm - b.torque_nm)
        speed.append(np.abs(a.qd))
    diff, speed = np.array(diff), np.array(speed)
    standing = np.array([np.std(diff[speed[:, j] == 0, j]) if np.any(speed[:, j] == 0) else np.nan for j in range(6)])
    moving = np.array([np.std(diff[speed[:, j] >= NOISE_RAMP_RAD_S, j]) if np.any(speed[:, j] >= NOISE_RAMP_RAD_S)
                       else np.nan for j in range(6)])
    return standing, moving


def test_standing_and_moving_joints_scatter_as_the_yaml_says():
    config = parse_config(_ur5e_data(), source="sim-ur5e.yaml")
    sim = config.simulation
    assert sim.noise_rest_nm is not None and np.all(np.array(sim.noise_rest_nm) < np.array(sim.noise_nm))
    standing, moving = _scatter(config)
    for j in range(6):
        if j in MOVING:
            assert moving[j] == pytest.approx(sim.noise_nm[j], rel=0.08), (j, moving, sim.noise_nm)
        else:
            assert np.isnan(moving[j])
            assert standing[j] == pytest.approx(sim.noise_rest_nm[j], rel=0.08), (j, standing, sim.noise_rest_nm)


def test_without_a_rest_level_a_standing_joint_is_as_noisy_as_a_moving_one():
    data = _ur5e_data()
    del data["simulation"]["noise_rest_nm"]
    config = parse_config(data, source="sim-ur5e.yaml")
    assert config.simulation.noise_rest_nm is None
    standing, moving = _scatter(config)
    for j in range(6):
        seen = moving[j] if j in MOVING else standing[j]
        assert seen == pytest.approx(config.simulation.noise_nm[j], rel=0.08), (j, standing, moving)


def test_the_noise_ramps_between_rest_and_motion():
    robot = SimRobot(SPECS["ur5e"](), q0_rad=np.zeros(6), noise_nm=1.0, noise_rest_nm=0.2)
    level = robot.noise_level_nm(np.array([0.0, NOISE_RAMP_RAD_S / 2, NOISE_RAMP_RAD_S, 1.0, -1.0, -0.01]))
    assert level == pytest.approx([0.2, 0.6, 1.0, 1.0, 1.0, 0.36])


@pytest.mark.parametrize("value, match", [
    ([0.1, 0.1, 0.1], r"simulation\.noise_rest_nm"),
    (-0.1, r"simulation\.noise_rest_nm"),
])
def test_a_wrong_rest_noise_is_refused_naming_the_key(value, match):
    with pytest.raises(ConfigError, match=match):
        parse_config(tweak(_ur5e_data(), "simulation.noise_rest_nm", value), source="sim-ur5e.yaml")
