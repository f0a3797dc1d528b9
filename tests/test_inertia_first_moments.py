"""The inertia fit corrects the sweeps' m·c with the wrist moves where the two agree, and holds it where they do not.

A static m·c error shows as inertia (a gravity torque that changes with the moving joint's angle correlates
with the PTP move's q̈), so the wrist moves update m and m·c with the sweeps' result as prior. Where the two
disagree beyond their σ, something the model lacks would drag m·c and the tensor with it: the
innovation test sees the disagreement and the fit holds m·c at the sweeps' result, saying why (here: sweeps
that claim more than they know).
The simulated EC66 with its YAML's noise and friction; a 4.5 kg long off-axis gripper the agent is not told.
"""

import numpy as np
import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.configuration.procedure import load_procedure
from payload_agent.configuration.wrist_procedure import load_wrist_procedure
from payload_agent.evaluation.wrist_inertia import identify_inertia
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.base import sim_robot_kwargs
from payload_agent.fakes.offline import record_wrist_moves
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.model.arm_geometry import ArmGeometry
from payload_agent.motion.planner import Plan, wrist_moves
from payload_agent.solvers.inertia_fit import NIS_LIMIT, fit_inertia

MASS, COG = 4.5, np.array([0.05, -0.03, 0.15])
TENSOR = 4.5 / 12.0 * np.diag([0.15 ** 2 + 0.35 ** 2, 0.10 ** 2 + 0.35 ** 2, 0.10 ** 2 + 0.15 ** 2])
COG_STD_M = 0.001
STATIC_ERROR_M = np.array([0.0015, -0.0015, 0.0015])  # what the sweeps got wrong: 1.5 σ per axis


@pytest.fixture(scope="module")
def setup():
    data = tweak(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), "safety.max_wrist_speed_percent", 100)
    cfg = parse_config(data, source="sim-ec66.yaml")
    geo = ArmGeometry(cfg.robot.kinematics, 0.0)
    margin = cfg.safety.joint_limit_margin_rad
    limits = [(a + margin, b - margin) for a, b in cfg.robot.joint_limits_rad[3:]]
    start = np.radians([0, -90, 90, 180, -270, -90])
    plan = Plan(load_procedure("paper_bd"), tuple(wrist_moves(cfg, load_wrist_procedure("wrist_inertia"), geo, limits,
                                                                 tuple(start))))
    return cfg, plan, start


def record(cfg, plan, start, payload, seed, effects=None):
    """One phase of wrist moves on the simulated arm; both phases share its gears (ripple phases), not its noise."""
    kw = sim_robot_kwargs(cfg)
    kw.update(q0_rad=start, seed=seed, payload=payload, ripple_seed=1)
    if effects is not None:
        kw["effects"] = effects
    return record_wrist_moves(SimRobot(SPECS[cfg.simulation.arm](), tick_s=0.008, **kw), plan)[0]


def static():
    c = COG + STATIC_ERROR_M
    return np.array([MASS, *(MASS * c)]), np.diag([0.003 * MASS, *(MASS * COG_STD_M,) * 3]) ** 2


def test_the_wrist_moves_correct_the_sweeps_first_moments_and_the_tensor_with_them(setup):
    cfg, plan, start = setup
    empty = record(cfg, plan, start, None, 11)
    loaded = record(cfg, plan, start, PayloadTruth.from_tensor(MASS, COG, TENSOR), 12)
    theta, cov = static()
    fit = fit_inertia(loaded, empty, cfg.robot.kinematics, theta, cov)
    held = fit_inertia(loaded, empty, cfg.robot.kinematics, theta, cov, update_static=False)
    assert fit.static_held is None and fit.static_nis <= NIS_LIMIT
    assert "as asked" in held.static_held and np.isnan(held.static_nis)
    c_upd = fit.theta[1:4] / fit.theta[0]
    print(f"CoM error mm: sweeps {1000 * STATIC_ERROR_M}, updated {np.round(1000 * (c_upd - COG), 2)}; "
          f"NIS {fit.static_nis:.2f}")
    assert np.linalg.norm(c_upd - COG) < 0.6 * np.linalg.norm(STATIC_ERROR_M)  # pulled towards the truth
    assert np.all(np.sqrt(np.diag(fit.cov)[1:4]) < MASS * COG_STD_M)  # and known better than the sweeps alone
    largest = float(np.max(np.linalg.eigvalsh(TENSOR)))
    err_upd = np.max(np.abs(fit.inertia_com()[0] - TENSOR)) / largest
    err_held = np.max(np.abs(held.inertia_com()[0] - TENSOR)) / largest
    print(f"tensor error / largest moment: updated {err_upd:.3f}, held {err_held:.3f}")
    assert err_upd < err_held and err_upd < 0.10
    res = identify_inertia(loaded, empty, cfg.robot.kinematics, theta, cov)
    assert res.static_held is None and res.to_json()["inertia"]["first_moments"].startswith("updated")


def test_wrist_moves_that_disagree_with_the_sweeps_leave_the_first_moments_held_saying_why(setup):
    cfg, plan, start = setup
    empty = record(cfg, plan, start, None, 13)
    loaded = record(cfg, plan, start, PayloadTruth.from_tensor(MASS, COG, TENSOR), 14)
    # sweeps 8 mm off on every axis while claiming 1 mm (what a tool that shifted between the parts would give)
    theta = np.array([MASS, *(MASS * (COG + 0.008))])
    cov = static()[1]
    fit = fit_inertia(loaded, empty, cfg.robot.kinematics, theta, cov)
    print(f"NIS {fit.static_nis:.1f}")
    assert fit.static_nis > NIS_LIMIT and "disagree with the sweeps" in fit.static_held
    assert np.array_equal(fit.theta[:4], theta)  # held at the sweeps' result
    held = fit_inertia(loaded, empty, cfg.robot.kinematics, theta, cov, update_static=False)
    assert np.allclose(fit.theta[4:], held.theta[4:]) and np.allclose(fit.cov, held.cov)
    res = identify_inertia(loaded, empty, cfg.robot.kinematics, theta, cov)
    assert any("held at the sweeps' result" in n for n in res.notes())
    assert res.to_json()["inertia"]["first_moments"] == "held at the sweeps' result"
