"""``simulation.dh_length_error_mm``: a simulated arm whose DH lengths are not the YAML's (issue 22: the plan's length
term was never run against an arm with length errors). Off by default; the shipped configs keep exact arms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.configuration.config import load_config, parse_config
from payload_agent.errors import ConfigError
from payload_agent.fakes.arms import SPECS, simulated_spec


def _lengths_mm(spec) -> np.ndarray:
    return 1000.0 * np.array([[row.a_m, row.d_m] for row in spec.dh])


def test_the_shipped_simulations_have_exact_arms():
    for path in sorted((ROOT / "configs").glob("sim-*.yaml")):
        sim = load_config(path).simulation
        assert sim.dh_length_error_mm == 0.0, path.name
        assert simulated_spec(sim) == SPECS[sim.arm](), path.name


@pytest.mark.parametrize("value,expect", [("0.5mm", "number"), (-0.1, ">= 0"), ([0.5, 0.5], "number"), (12, "<= 5")])
def test_a_malformed_value_is_refused_by_name(sim_ec66_data, value, expect):
    with pytest.raises(ConfigError) as info:
        parse_config(tweak(sim_ec66_data, "simulation.dh_length_error_mm", value), source="sim-ec66.yaml")
    assert info.value.key_path == "simulation.dh_length_error_mm"
    assert expect in str(info.value) and "sim-ec66.yaml" in str(info.value), str(info.value)


def test_each_nonzero_length_is_off_within_the_bound_seeded(sim_ec66_data):
    """Every non-zero a and d of the simulated arm moves by a uniform draw within ±0.5 mm, the same for a seed and
    another for another seed; structural zeros stay zero. The agent's kinematics (the YAML's) stay nominal."""
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text())
    data["simulation"]["dh_length_error_mm"] = 0.5
    config = parse_config(data, source="sim-ur5e.yaml")
    nominal, off = _lengths_mm(SPECS["ur5e"]()), _lengths_mm(simulated_spec(config.simulation))
    moved = off - nominal
    assert np.all(np.abs(moved) <= 0.5) and np.all(moved[nominal == 0] == 0.0)
    assert np.count_nonzero(moved) == np.count_nonzero(nominal)  # every non-zero length moved
    assert np.std(moved[nominal != 0]) > 0.1  # spread over the band, not a constant
    assert np.array_equal(off, _lengths_mm(simulated_spec(config.simulation)))
    data["simulation"]["seed"] = 2
    other = _lengths_mm(simulated_spec(parse_config(data, source="sim-ur5e.yaml").simulation))
    assert not np.array_equal(off, other)
    assert [r.a_m for r in config.robot.kinematics.rows] == pytest.approx([r.a_m for r in SPECS["ur5e"]().dh])


def test_the_simulated_controller_moves_the_arm_with_the_erroneous_lengths(sim_ec66_data):
    """The simulated Elite controller built from the YAML (as `run` builds it) carries the drawn arm, whose torques
    at a pose differ from the nominal arm's by what the length errors make: a few mN·m on joint 2 for 2.5 kg."""
    from payload_agent.fakes.elite_ec import FakeEliteController
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.fakes.sim_robot import SimRobot

    config = parse_config(tweak(sim_ec66_data, "simulation.dh_length_error_mm", 0.5), source="sim-ec66.yaml")
    controller = FakeEliteController.from_config(config, in_process=True)
    spec = controller.robot.spec
    assert spec == simulated_spec(config.simulation) and spec != SPECS["ec66"]()
    q = np.radians([0.0, -60.0, 60.0, -90.0, 90.0, 0.0])
    torques = []
    for arm in (spec, SPECS["ec66"]()):
        robot = SimRobot(arm, q0_rad=q, tick_s=0.008, seed=1)
        robot.set_payload(PayloadTruth.point(2.5, [30.0, -20.0, 60.0]))
        torques.append(robot.step().torque_nm)
    diff = np.abs(torques[0] - torques[1])
    assert 1e-4 < diff[1] < 0.1, diff


def test_seeded_runs_sets_the_key_for_every_seed(tmp_path: Path):
    from benchmarks import seeded_runs

    config = seeded_runs.seed_config("sim-ur5e", 3, tmp_path, dh_error_mm=0.5)
    assert config.simulation.dh_length_error_mm == 0.5 and config.simulation.seed == 3
