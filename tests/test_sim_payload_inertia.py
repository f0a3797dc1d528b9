"""Simulated tools with a full inertia tensor: the YAML takes it (and refuses what no body has), the physics
applies it with its principal axes turned, and the payload's Newton–Euler regressor agrees to 1e-9."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.configuration.config import load_config
from payload_agent.errors import ConfigError
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import regressor

pytest.importorskip("mujoco")
from payload_agent.fakes.arms import SPECS  # noqa: E402
from payload_agent.fakes.physics import ArmPhysics, PayloadTruth  # noqa: E402

# an off-axis gripper: principal axes turned away from the flange's
TENSOR = [[0.030, -0.004, 0.003], [-0.004, 0.040, 0.005], [0.003, 0.005, 0.025]]


def test_a_turned_tensor_reaches_the_physics_as_given():
    spec = SPECS["ur5e"]()
    kin = Kinematics(spec.dh)
    truth = PayloadTruth.from_tensor(2.2, (0.03, -0.05, 0.11), TENSOR)
    np.testing.assert_allclose(truth.inertia_com_kgm2, TENSOR, atol=1e-12)
    with_payload, without = ArmPhysics(spec, truth), ArmPhysics(spec, None)
    m, c = truth.mass_kg, np.array(truth.cog_m)
    io = np.array(TENSOR) + m * (c @ c * np.eye(3) - np.outer(c, c))  # about the flange origin
    theta = np.array([m, *(m * c), io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])
    q, qd, qdd = np.random.default_rng(4).normal(size=(3, 12, 6))
    W = regressor.payload_regressor(kin, q, qd, qdd)
    for k in range(12):
        expected = with_payload.rigid_torque(q[k], qd[k], qdd[k]) - without.rigid_torque(q[k], qd[k], qdd[k])
        np.testing.assert_allclose(W[k] @ theta, expected, atol=1e-9)


def _sim_config(tmp_path, tensor):
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text())
    data = tweak(data, "simulation.payload.inertia_com_kgm2", tensor)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_yaml_takes_a_tensor_and_refuses_one_no_body_has(tmp_path):
    config = load_config(_sim_config(tmp_path, TENSOR))
    assert config.simulation.payload.inertia_com_kgm2 == tuple(tuple(r) for r in TENSOR)
    for bad, words in (([[0.01, 0, 0], [0, 0.01, 0]], "three rows of three numbers"),
                       ([[0.01, 0.002, 0], [0, 0.01, 0], [0, 0, 0.01]], "not symmetric"),
                       ([[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.05]], "no rigid body has it")):
        with pytest.raises(ConfigError, match=words) as err:
            load_config(_sim_config(tmp_path, bad))
        assert err.value.key_path.endswith("simulation.payload.inertia_com_kgm2")


def test_the_shipped_sim_ur5e_tool_has_a_tensor_and_its_inertia_is_identified_not_refused():
    """configs/sim-ur5e.yaml as shipped: the inertia part on and a tool with a full tensor, whose wrist moves (its
    own noise and friction, recorded on the in-process simulated arm at the UR's 500 Hz) carry the inertia."""
    from payload_agent.evaluation.wrist_inertia import identify_inertia
    from payload_agent.fakes.base import sim_robot_kwargs
    from payload_agent.fakes.offline import record_wrist_moves
    from payload_agent.fakes.sim_robot import SimRobot
    from payload_agent.motion.planner import Plan, make_plan

    cfg = load_config(ROOT / "configs" / "sim-ur5e.yaml")
    truth = np.asarray(cfg.simulation.payload.inertia_com_kgm2)
    assert cfg.procedure.inertia and truth.shape == (3, 3)
    plan = make_plan(cfg)
    last = plan.moves.index(plan.sweeps[-1])
    wrist = Plan(plan.procedure, plan.moves[last + 1:])
    start = np.asarray(plan.moves[last].target_rad)
    m, c = cfg.simulation.payload.mass_kg, np.asarray(cfg.simulation.payload.cog_mm) / 1000.0
    phases = {}
    for name, payload, seed in (("empty", None, 11), ("loaded", PayloadTruth.from_tensor(m, c, truth), 12)):
        kw = sim_robot_kwargs(cfg)
        kw.update(q0_rad=start, seed=seed, payload=payload)
        phases[name] = record_wrist_moves(SimRobot(SPECS[cfg.simulation.arm](), tick_s=0.002, **kw), wrist)[0]
    static = np.array([m, *(m * c)]), np.diag([0.005 * m, *(0.001 * m,) * 3]) ** 2  # what the sweeps give
    res = identify_inertia(phases["loaded"], phases["empty"], cfg.robot.kinematics, *static)
    err = res.estimate_kgm2 - truth
    print(f"sim-ur5e inertia: error {np.round(err, 4).tolist()}, σ {np.round(res.std_kgm2, 4).tolist()}")
    assert res.refused is None, res.refused
    assert np.all(np.abs(err) <= 3.0 * res.std_kgm2)
    assert np.max(np.abs(err)) < 0.35 * np.max(np.linalg.eigvalsh(truth))
