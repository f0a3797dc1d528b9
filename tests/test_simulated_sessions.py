"""Each session of a simulated robot draws its own sensor noise on the same arm, as a real drive does after a restart.

A calibration, a stored baseline and the run after them are separate sessions. With one noise draw for all of them
their errors cancelled in the subtraction: in session 19 the online CoM errors after ``calibrate`` were less than half
the offline ones, and the reported σ looked too wide against them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from conftest import tweak
from payload_agent.configuration.config import parse_config
from payload_agent.fakes.elite_ec import FakeEliteController
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.session.simulation import count_session


def _torques(config, session: int, ticks: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cfg = dataclasses.replace(config, simulation=dataclasses.replace(config.simulation, session=session))
    robot = FakeEliteController.from_config(cfg, in_process=True).robot
    robot.set_payload(PayloadTruth.point(2.0, [30.0, -20.0, 60.0]))
    torques = np.array([robot.step().torque_nm for _ in range(ticks)])
    return torques, robot._ripple_phases, robot.noise_level_nm(np.zeros(6))  # (it stands: the noise at rest)


def test_sessions_are_counted_in_the_robots_state_folder(sim_ec66_data, tmp_path):
    config = parse_config(tweak(sim_ec66_data, "storage.state_dir", str(tmp_path)), source="sim-ec66.yaml")
    assert [count_session(config) for _ in range(3)] == [0, 1, 2]
    other = parse_config(tweak(sim_ec66_data, "storage.state_dir", str(tmp_path / "other")), source="sim-ec66.yaml")
    assert count_session(other) == 0  # another robot state: its own count


def test_each_session_draws_its_own_noise_on_the_same_arm(sim_ec66_data):
    data = tweak(sim_ec66_data, "simulation.effects", {"torque_ripple": {"amplitude_nm": [0.3] * 6}})
    config = parse_config(data, source="sim-ec66.yaml")
    first, phases, noise = _torques(config, 0)
    again, phases_again, _ = _torques(config, 0)
    later, phases_later, _ = _torques(config, 1)
    assert np.array_equal(first, again)  # a seeded session is reproducible
    assert np.array_equal(phases, phases_later) and np.array_equal(phases, phases_again)  # the same gears
    diff = later - first
    moving = noise > 0
    # different draws: the difference has the spread of two independent noises (√2 σ), not zero ...
    assert np.all(np.abs(diff.std(axis=0)[moving] / (np.sqrt(2) * noise[moving]) - 1) < 0.25), diff.std(axis=0)
    # ... around the same torques: the arm, payload and standing pose are the same
    assert np.all(np.abs(diff.mean(axis=0)[moving]) < 4 * np.sqrt(2) * noise[moving] / np.sqrt(len(diff)))
