"""The simulated robots draw each motion's noise from (seed, session, motion number), by default.

Without it the noise is one stream drawn per tick, and which draws a motion gets depends on the tick its command
arrived at: with the elastic clock, on how loaded the host is, so every run of a seeded test was a new draw and a
statistic at a fixed α failed at its rate. Per motion, a seeded session repeats however late the commands land;
the noise must stay what a real drive's is: as large, white within a motion, and new for every motion and session.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.base import sim_robot_kwargs
from payload_agent.fakes.sim_robot import SimRobot

SIM_CONFIGS = ("sim-ec66", "sim-ur5e", "sim-ur5e-modbus", "sim-canopen-arm")


def _config(name: str = "sim-ec66", **keys):
    data = yaml.safe_load((ROOT / "configs" / f"{name}.yaml").read_text())
    for key, value in keys.items():
        data = tweak(data, f"simulation.{key}", value)
    return parse_config(data, source=f"{name}.yaml")


def _robot(config, **overrides) -> SimRobot:
    kw = {**sim_robot_kwargs(config), **overrides}
    return SimRobot(SPECS[config.simulation.arm](), tick_s=0.008, **kw)


@pytest.mark.parametrize("name", SIM_CONFIGS)
def test_the_shipped_simulations_draw_noise_per_motion_unless_the_yaml_says_otherwise(name):
    assert sim_robot_kwargs(_config(name))["noise_per_move"] is True
    assert sim_robot_kwargs(_config(name, noise_per_move=False))["noise_per_move"] is False


def test_a_seeded_motion_draws_the_same_noise_however_late_its_command_arrives():
    """The shipped sim-ec66 (effort noise, angle noise, timestamp jitter): a motion's samples depend on the seed and
    the motion, not on the simulated tick its command arrived at (a loaded host delays commands in simulated time)."""

    def motion(idle_ticks, config):
        robot = _robot(config, session=2)
        q0 = np.asarray(robot.snapshot().q_true)
        for _ in range(idle_ticks):
            robot.step()
        robot.move_joints(q0 + np.radians([0.0, -5.0, 0.0, 0.0, 0.0, 0.0]), 0.25, 1.2)
        t0, rows = robot.now(), []
        while (s := robot.step()).moving:
            rows.append(np.concatenate([[s.t - t0], s.q, s.torque_nm]))
        return np.array(rows)

    config = _config()
    early, late = motion(3, config), motion(40, config)
    assert len(early) > 50 and np.allclose(early, late, rtol=0, atol=1e-9)  # (float rounding of the start time)
    # per tick (noise_per_move: false), the same motion draws other noise
    per_tick = _config(noise_per_move=False)
    early, late = motion(3, per_tick), motion(40, per_tick)
    assert len(early) == len(late) and not np.allclose(early[:, 7:], late[:, 7:])


def _motion_noise(config, session: int = 0, motions: int = 24) -> list[dict[str, np.ndarray]]:
    """Per motion, the reported effort, angles and timestamps minus the noise-free ones (a second robot without
    noise doing the same moves): joint 2 back and forth over 8°, a few standing ticks between the motions."""
    noisy = _robot(config, session=session)
    clean = _robot(config, session=session, noise_nm=0.0, noise_rest_nm=0.0)
    q0 = np.asarray(noisy.snapshot().q_true)
    out = []
    for k in range(motions):
        target = q0 + np.radians([0.0, -8.0 if k % 2 == 0 else 0.0, 0.0, 0.0, 0.0, 0.0])
        for r in (noisy, clean):
            for _ in range(3 + k % 4):
                r.step()
            r.move_joints(target, 0.1, 1.0)
        rows = []
        while True:
            a, b = noisy.step(), clean.step()
            if not a.moving:
                break
            rows.append((a.torque_nm - b.torque_nm, a.q - a.q_true, a.t - a.t_true))
        out.append(dict(effort=np.array([r[0] for r in rows]), angle=np.array([r[1] for r in rows]),
                        time=np.array([r[2] for r in rows])))
    return out


def test_noise_drawn_per_motion_is_as_large_and_as_white_as_per_tick_and_new_every_motion_and_session():
    """Effort noise (the in-motion level of sim-ec66), angle noise and timestamp jitter: the same standard
    deviation per tick or per motion, no correlation from one sample to the next, none between one motion's
    samples and the next motion's, none between the same motion of two sessions."""
    per_move = _motion_noise(_config())
    per_tick = _motion_noise(_config(noise_per_move=False))
    other_session = _motion_noise(_config(), session=1)
    sim = _config().simulation
    n = sum(len(m["effort"]) for m in per_move)
    assert n > 3000
    # a standard deviation from n Gaussian samples scatters by 1/√(2n) relative (≈ 1.3 % here); 5 % is ~4 σ
    for key, level in (("effort", sim.noise_nm[1]), ("angle", sim.angle_noise_rad[1])):
        a = np.concatenate([m[key] for m in per_move])[:, 1]
        b = np.concatenate([m[key] for m in per_tick])[:, 1]
        assert np.std(a) == pytest.approx(level, rel=0.05) and np.std(b) == pytest.approx(level, rel=0.05)
        assert np.std(a) == pytest.approx(np.std(b), rel=0.07)
    jitter = np.concatenate([m["time"] for m in per_move])
    assert np.std(jitter) == pytest.approx(np.std(np.concatenate([m["time"] for m in per_tick])), rel=0.07)
    # correlations: a correlation of n independent pairs scatters by 1/√n; 4/√n bounds it at ~4 σ. Motion k
    # against motion k + 2 (the same move) and against the other session's motion k: pooled, and each pair
    # (0.5, ~7 σ at ~190 samples a motion: a motion that repeated another's draws would give 1)
    for key in ("effort", "angle"):
        x = [m[key][:, 1] - m[key][:, 1].mean() for m in per_move]
        lag1 = sum(float(v[1:] @ v[:-1]) for v in x) / sum(float(v @ v) for v in x)
        assert abs(lag1) < 4 / np.sqrt(n), (key, lag1)
        pairs = [(x[k], x[k + 2]) for k in range(len(x) - 2)]
        pairs += [(v, other_session[k][key][:, 1] - other_session[k][key][:, 1].mean()) for k, v in enumerate(x)]
        assert all(len(u) == len(v) for u, v in pairs)
        each = [float(u @ v) / np.sqrt(float(u @ u) * float(v @ v)) for u, v in pairs]
        pooled = sum(float(u @ v) for u, v in pairs) / np.sqrt(sum(float(u @ u) for u, _ in pairs)
                                                               * sum(float(v @ v) for _, v in pairs))
        n_pairs = sum(len(u) for u, _ in pairs)
        assert max(map(abs, each)) < 0.5 and abs(pooled) < 4 / np.sqrt(n_pairs), (key, each, pooled)
