"""The physics core's error sources (fakes/effects.py): each one does what a real arm does, and nothing else.

Every test drives a SimRobot tick by tick (no clock thread, no wall time) and compares what the
controller reports (SimState.t, .q, .torque_nm) with the truth it also carries (t_true, q_true,
q_link) or with the rigid-body model.
"""

import math

import numpy as np
import pytest

from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.effects import PhysicsEffects, ToolCable, TorqueRipple
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot

Q0 = np.radians([0.0, -60.0, 80.0, 10.0, -70.0, 20.0])
TICK = 0.008
PAYLOAD = PayloadTruth.point(2.0, (40.0, -25.0, 70.0))


def robot(**effects) -> SimRobot:
    return SimRobot(ec66_spec(), q0_rad=Q0, tick_s=TICK, seed=3, effects=PhysicsEffects(**effects))


def test_default_is_the_ideal_arm_and_reports_the_truth():
    r = robot()
    for _ in range(5):
        s = r.step()
        assert s.t == s.t_true and np.array_equal(s.q, s.q_true) and np.array_equal(s.q_link, s.q_true)
    assert np.allclose(s.torque_nm, r.physics.rigid_torque(Q0, np.zeros(6), np.zeros(6)), atol=1e-12)


def test_angle_noise_and_timestamp_jitter_in_what_is_reported_clock_exact():
    r = robot(angle_noise_rad=1e-5, time_jitter_s=1e-4)
    states = [r.step() for _ in range(3000)]
    dq = np.array([s.q - s.q_true for s in states])
    dt = np.array([s.t - s.t_true for s in states])
    assert np.std(dq) == pytest.approx(1e-5, rel=0.1)
    assert np.std(dt) == pytest.approx(1e-4, rel=0.1)
    assert np.max(np.abs(dt)) <= 0.4 * TICK + 1e-15
    assert np.all(np.diff([s.t for s in states]) > 0)  # stamps stay in order
    assert np.allclose(np.diff([s.t_true for s in states]), TICK)  # the simulated clock is exact
    assert r.now() == pytest.approx(3000 * TICK)
    # the effort noise stream is not disturbed by the angle/time noise
    plain = robot()
    assert np.allclose(plain.step().torque_nm, SimRobot(ec66_spec(), q0_rad=Q0, tick_s=TICK, seed=3).step().torque_nm)


def test_moves_start_from_the_exact_angles_not_the_noisy_ones():
    r = robot(angle_noise_rad=1e-3)
    r.step()
    target = Q0 + np.radians([0, 5, 0, 0, 0, 0])
    r.move_joints(target, 0.5, 2.0)
    states = [r.step() for _ in range(400)]
    assert not states[-1].moving
    assert np.allclose(states[-1].q_true, target, atol=1e-12)


def test_zero_offset_and_elasticity_put_the_link_where_gravity_acts():
    zero = np.radians([0.0, 0.03, -0.02, 0.01, 0.02, -0.01])
    k = np.array([3e4, 3e4, 3e4, 5.5e3, 5.5e3, 5.5e3])
    r = robot(zero_offset_rad=zero, stiffness_nm_per_rad=k)
    r.set_payload(PAYLOAD)
    s = [r.step() for _ in range(3)][-1]
    tau = s.torque_nm
    assert np.allclose(s.q_link, Q0 - zero - tau / k, atol=1e-9)  # link = motor − offset − τ/k
    assert np.allclose(tau, r.physics.rigid_torque(s.q_link, np.zeros(6), np.zeros(6)), atol=1e-6)
    # the twist is what a strain-wave gear shows under this load: tens of µrad, well below the offsets' scale
    assert 1e-5 < np.max(np.abs(tau / k)) < 2e-3


def test_asymmetric_coulomb_and_temperature_dependent_friction():
    f = FrictionParams(coulomb_nm=4.0, asymmetry=0.1, load_ratio=0.0)
    up, down, still = (f.torque(np.full(6, v), np.zeros(6))[1] for v in (0.2, -0.2, 0.0))
    assert up == pytest.approx(4.0 * 1.1) and down == pytest.approx(-4.0 * 0.9) and still == 0.0
    fx = PhysicsEffects(friction_per_c=-0.01, tool_warmup_c=10.0)
    r = SimRobot(ec66_spec(), q0_rad=Q0, tick_s=TICK, effects=fx)
    assert np.allclose(r.temperatures_c(), 25.0)
    r.set_payload(PAYLOAD)  # the tool run: joints warmer, friction lower
    assert np.allclose(r.temperatures_c(), 35.0)
    assert np.allclose(fx.friction_factor(r.temperatures_c()), 0.9)
    r.set_joint_temperatures([40.0] * 6)
    assert np.allclose(r.temperatures_c(), 50.0)


def test_friction_changes_with_temperature_in_the_reported_effort():
    def moving_effort(fx: PhysicsEffects, payload) -> float:
        friction = FrictionParams(coulomb_nm=[0, 4, 3, 1, 1, 0.5])
        r = SimRobot(ec66_spec(), q0_rad=Q0, tick_s=TICK, friction=friction, effects=fx, payload=payload)
        r.move_joints(Q0 + np.radians([0, 20, 0, 0, 0, 0]), 0.3, 2.0)
        s = [r.step() for _ in range(80)][-1]  # cruising at 0.3 rad/s
        assert abs(s.qd[1] - 0.3) < 1e-9
        return s.torque_nm[1] - r.physics.rigid_torque(s.q_link, s.qd, s.qdd)[1]

    warm = PhysicsEffects(friction_per_c=-0.01, tool_warmup_c=10.0)
    assert moving_effort(warm, None) == pytest.approx(4.0, abs=1e-6)  # baseline: cold
    assert moving_effort(warm, PAYLOAD) == pytest.approx(3.6, abs=1e-6)  # tool run: 10 °C warmer, −10 %


def test_torque_ripple_follows_the_gear_mesh_and_grows_with_load():
    rip = TorqueRipple(amplitude_nm=0.3, load_ratio=0.01, gear_ratio=100, once_per_rev_fraction=0.0)
    phases = np.zeros((6, 2))
    q = np.full(6, math.pi / 400)  # a quarter mesh period: sin(2·100·q) = 1
    assert np.allclose(rip.torque(q, np.zeros(6), phases), 0.3)
    assert np.allclose(rip.torque(q, np.full(6, 20.0), phases), 0.5)
    assert np.allclose(rip.torque(q + math.pi / 100, np.zeros(6), phases), 0.3)  # period 2π/200
    r = robot(ripple=TorqueRipple(amplitude_nm=[0, 0.3, 0, 0, 0, 0]))
    s = r.step()
    ideal = r.physics.rigid_torque(Q0, np.zeros(6), np.zeros(6))
    extra = s.torque_nm - ideal
    assert abs(extra[1]) <= 0.3 * 1.1 + 1e-9 and np.allclose(np.delete(extra, 1), 0.0)


def test_effort_quantisation():
    r = robot(effort_quantum_nm=[0.15, 0.15, 0.15, 0.028, 0.028, 0.028])
    s = r.step()
    steps = s.torque_nm / np.array([0.15, 0.15, 0.15, 0.028, 0.028, 0.028])
    assert np.allclose(steps, np.round(steps), atol=1e-9)
    assert np.allclose(s.torque_nm, r.physics.rigid_torque(Q0, np.zeros(6), np.zeros(6)), atol=0.076)


def test_tool_cable_pulls_on_the_wrist_only_with_the_tool_mounted():
    k = (0.3, 0.3, 0.3)
    r = robot(tool_cable=ToolCable(k))
    ideal = robot()
    for rr in (r, ideal):
        rr.step()
    r.set_payload(PAYLOAD)
    ideal.set_payload(PAYLOAD)
    turn = np.radians([0, 0, 0, 30, -40, 50])
    for rr in (r, ideal):
        rr.move_joints(Q0 + turn, 1.0, 3.0)
        while rr.step().moving:
            pass
    extra = r.step().torque_nm - ideal.step().torque_nm
    assert np.allclose(extra[:3], 0.0, atol=1e-9)  # both ends distal to joint 3
    assert np.allclose(extra[3:], np.asarray(k) * turn[3:], atol=1e-9)  # relaxed where the tool was mounted
    r.set_payload(None)
    ideal.set_payload(None)
    assert np.allclose(r.step().torque_nm, ideal.step().torque_nm, atol=1e-12)


def test_invalid_effects_are_refused():
    with pytest.raises(ValueError):
        PhysicsEffects(angle_noise_rad=-1e-5)
    with pytest.raises(ValueError):
        PhysicsEffects(coulomb_asymmetry=1.2)


class _PerTick(PhysicsEffects):
    """The effects' per-tick pieces as they were computed before they were cached per instance (session 20)."""

    @property
    def compliance_rad_per_nm(self) -> np.ndarray:
        k = np.asarray(self.stiffness_nm_per_rad)
        return np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), 0.0)

    @property
    def elastic(self) -> bool:
        return any(k > 0 for k in self.stiffness_nm_per_rad)

    def quantise(self, tau: np.ndarray) -> np.ndarray:
        qn = np.asarray(self.effort_quantum_nm)
        return np.where(qn > 0, np.round(tau / np.where(qn > 0, qn, 1.0)) * qn, tau)

    def angle_noise(self, rng: np.random.Generator) -> np.ndarray:
        sigma = np.asarray(self.angle_noise_rad)
        return rng.normal(0.0, 1.0, 6) * sigma if sigma.any() else np.zeros(6)


@pytest.mark.parametrize("effects", [{}, dict(stiffness_nm_per_rad=(0, 3e4, 2e4, 0, 0, 0), effort_quantum_nm=0.01,
                                              angle_noise_rad=1e-5, time_jitter_s=1e-4, friction_per_c=0.01,
                                              tool_warmup_c=3.0, ripple=TorqueRipple(amplitude_nm=0.2),
                                              tool_cable=ToolCable((0.1, 0.1, 0.1)))], ids=["ideal", "every_effect"])
def test_the_effects_cached_per_instance_give_every_sample_as_computed_per_tick(effects):
    """What depends on the frozen effects alone is computed once per instance (every simulated tick asked for it):
    a seeded arm moving with a payload reports exactly the samples it reported when each tick computed it."""
    runs = []
    for cls in (PhysicsEffects, _PerTick):
        r = SimRobot(ec66_spec(), q0_rad=Q0, tick_s=TICK, seed=3, noise_nm=0.3, effects=cls(**effects))
        r.set_payload(PAYLOAD)
        r.move_joints(Q0 + np.radians([0.0, 20.0, -15.0, 10.0, 10.0, 30.0]), 0.5, 2.0)
        runs.append([r.step() for _ in range(400)])
    assert runs[0][-1].q_true[1] != runs[0][0].q_true[1]  # it moved
    for a, b in zip(*runs):
        assert a.t == b.t and np.array_equal(a.q, b.q) and np.array_equal(a.torque_nm, b.torque_nm)
        assert np.array_equal(a.q_link, b.q_link)
