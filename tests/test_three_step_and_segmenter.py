"""Segmenter and three-step solver on data from the simulator's physics (MuJoCo), no sockets."""

import numpy as np
import pytest

from conftest import tweak
from payload_agent.configuration.config import parse_config
from payload_agent.analysis.delta import subtract_all, window_of
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import three_step

TRUTH = PayloadTruth.point(2.3, (70.0, 65.0, 50.0))  # the paper's simulation group 2 (Table 1)


def _runs(cfg, friction, noise, payload=TRUTH, seed=0):
    plan = make_plan(cfg)
    robot = SimRobot(ec66_spec(), q0_rad=np.radians(cfg.simulation.start_deg), tick_s=0.008,
                     friction=friction, noise_nm=noise, seed=seed)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(payload)
    loaded, _ = record_plan(robot, plan)
    return plan, robot, empty, loaded


@pytest.fixture(scope="module")
def fast_cfg():
    import yaml
    from conftest import ROOT

    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    # without the inertia part: its 12 wrist moves come after the same 8 sweeps, are no sweeps for the segmenter
    # or the three-step solver, and cost half the simulated motion and the plan's wrist search (tests/test_wrist_*)
    return parse_config(tweak(tweak(data, "procedure.speed_percent", 5), "procedure.inertia", False))


def test_segmenter_keeps_only_constant_speed(fast_cfg):
    plan = make_plan(fast_cfg)
    robot = SimRobot(ec66_spec(), q0_rad=np.radians(fast_cfg.simulation.start_deg), tick_s=0.008)
    states_by_sweep = {}
    for move in plan.moves:
        robot.move_joints(move.target_rad, move.speed_rad_s, move.accel_rad_s2)
        states = [robot.step()]
        while states[-1].moving:
            states.append(robot.step())
        states += [robot.step() for _ in range(20)]
        if move.sweep:
            states_by_sweep[move.sweep] = (move, states)
    from payload_agent.recording.rundata import SweepData

    for key, (move, states) in states_by_sweep.items():
        j = key.joint - 1
        t = np.array([s.t for s in states])
        q = np.array([s.q for s in states])
        qd = np.array([s.qd for s in states])[:, j]
        qdd = np.array([s.qdd for s in states])[:, j]
        w = window_of(SweepData(key, t, q, np.zeros_like(q), key.name))
        assert np.all(qdd[w.slice] == 0), f"{key.name}: window includes acceleration"
        assert w.speed_rad_s == pytest.approx(qd[w.slice][0], rel=1e-6)
        cruise = np.flatnonzero(np.abs(qd - move.speed_rad_s * np.sign(qd[w.start])) < 1e-9)
        assert len(w) >= 0.95 * len(cruise), f"{key.name}: window keeps {len(w)} of {len(cruise)} cruise samples"


def test_three_step_exact_on_noise_free_simulation(fast_cfg):
    friction = FrictionParams(coulomb_nm=[4, 4, 3, 1, 1, .5], viscous_nm_s_rad=[8, 8, 5, 1, 1, .5])
    plan, robot, empty, loaded = _runs(fast_cfg, friction, 0.0)
    est = three_step.solve(subtract_all(loaded, empty), fast_cfg.robot.kinematics)
    assert est.mass_kg == pytest.approx(TRUTH.mass_kg, rel=1e-6)
    for got, want in zip(est.cog_m, TRUTH.cog_m):
        assert got == pytest.approx(want, rel=1e-6)


def test_three_step_with_noise_is_close(fast_cfg):
    friction = FrictionParams(coulomb_nm=3.0, viscous_nm_s_rad=5.0)
    plan, robot, empty, loaded = _runs(fast_cfg, friction, 0.3, seed=4)
    est = three_step.solve(subtract_all(loaded, empty), fast_cfg.robot.kinematics)
    assert abs(est.mass_kg - TRUTH.mass_kg) < 0.03
    assert np.max(np.abs(np.array(est.cog_m) - TRUTH.cog_m)) < 0.005
    assert all(0.2 < r < 1.0 for r in est.residual_rms_nm.values()), est.residual_rms_nm


def test_a_window_found_from_the_data_is_kept_by_the_samples_content(fast_cfg):
    """Without a command the window is searched in the data, once per content (``segmenter._window_from_bytes``):
    equal samples in other arrays (a copy, an effort with noise added) get the window computed the first time, the
    same as computed afresh; samples changed in place (the joint stalled mid-sweep) get their own."""
    import dataclasses

    from payload_agent.analysis import segmenter
    from payload_agent.recording.rundata import SweepData

    _, _, _, loaded = _runs(fast_cfg, FrictionParams(), 0.3, seed=4)
    sweep = loaded[next(k for k in loaded if k.direction == "up")]
    j = sweep.key.joint - 1
    first = window_of(sweep)
    assert first == segmenter._window_from_data(sweep.t, sweep.q[:, j], sweep.source)
    hits = segmenter._window_from_bytes.cache_info().hits
    noisy = dataclasses.replace(sweep, effort_nm=sweep.effort_nm + 1.0)
    copied = SweepData(sweep.key, sweep.t.copy(), sweep.q.copy(), sweep.effort_nm, sweep.source)
    assert window_of(noisy) == first and window_of(copied) == first
    assert segmenter._window_from_bytes.cache_info().hits == hits + 2
    middle = (first.start + first.stop) // 2
    copied.q[middle:, j] = copied.q[middle, j]  # in place: the joint stops half-way through its cruise
    stalled = window_of(copied)
    assert stalled != first and stalled.stop <= middle + 1
    assert stalled == segmenter._window_from_data(copied.t, copied.q[:, j], copied.source)
