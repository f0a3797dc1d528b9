"""The ``simulation.effects`` YAML reaches the physics core; the remedies undo what they claim to.

- a robot YAML's angle noise, jitter and effects arrive in the SimRobot a simulated controller builds;
- a misspelt effect key is refused naming its path;
- with the declared stiffness, compensating joint elasticity recovers the rigid arm's estimate;
- the declared zero-offset and stiffness uncertainties widen σ;
- the tool-cable check fails on a strong cable and names it, and passes without one; the wrist
  offsets it tests are sized from the data for σ.
"""

import numpy as np
import pytest

from payload_agent.analysis.combine import add_combined
from payload_agent.analysis.delta import subtract_all
from payload_agent.configuration.config import JointSystematicsConfig, parse_config
from payload_agent.errors import ConfigError
from payload_agent.evaluation import cable_check, systematics
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.base import sim_robot_kwargs
from payload_agent.fakes.effects import PhysicsEffects, ToolCable
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general

from conftest import tweak

EFFECTS = {
    "zero_offset_deg": [0.02, -0.03, 0.01, 0.0, 0.02, -0.01],
    "stiffness_nm_per_rad": [3.0e4, 3.0e4, 3.0e4, 5.5e3, 5.5e3, 5.5e3],
    "coulomb_asymmetry": 0.1,
    "temperature": {"friction_per_c": -0.01, "tool_warmup_c": 8},
    "torque_ripple": {"amplitude_nm": [0.3, 0.3, 0.3, 0.05, 0.05, 0.05], "load_ratio": 0.01},
    "effort_quantum_nm": [0.15, 0.15, 0.15, 0.028, 0.028, 0.028],
    "tool_cable": {"stiffness_nm_per_rad": [0.02, 0.02, 0.02]},
}
TRUTH = PayloadTruth.point(2.0, (40.0, -25.0, 70.0))


def _config(data):
    return parse_config(data, source="sim-ec66.yaml")


def test_simulation_effects_reach_the_physics_core(sim_ec66_data):
    data = tweak(sim_ec66_data, "simulation.angle_noise_rad", 1e-5)
    data = tweak(data, "simulation.timestamp_jitter_ms", 0.1)
    data = tweak(data, "simulation.effects", EFFECTS)
    config = _config(data)
    fx = sim_robot_kwargs(config)["effects"]
    assert fx.angle_noise_rad == (1e-5,) * 6 and fx.time_jitter_s == pytest.approx(1e-4)
    assert np.allclose(fx.zero_offset_rad, np.radians(EFFECTS["zero_offset_deg"]))
    assert fx.stiffness_nm_per_rad[0] == 3.0e4 and fx.coulomb_asymmetry == (0.1,) * 6
    assert fx.friction_per_c == -0.01 and fx.tool_warmup_c == 8
    assert fx.ripple.amplitude_nm[0] == 0.3 and fx.effort_quantum_nm[5] == 0.028
    assert fx.tool_cable.stiffness_nm_per_rad == (0.02, 0.02, 0.02)
    robot = SimRobot(ec66_spec(), tick_s=0.008, **sim_robot_kwargs(config))
    s = robot.step()
    assert not np.array_equal(s.q, s.q_true) and s.t != s.t_true
    assert np.allclose(robot.friction.asymmetry, 0.1)


def test_a_misspelt_effect_key_is_refused_naming_it(sim_ec66_data):
    data = tweak(sim_ec66_data, "simulation.effects", {"tool_cable": {"stiffnes_nm_per_rad": 0.1}})
    with pytest.raises(ConfigError, match=r"simulation\.effects\.tool_cable\.stiffnes_nm_per_rad"):
        _config(data)
    data = tweak(sim_ec66_data, "simulation.effects", {"zero_offset_deg": 20})
    with pytest.raises(ConfigError, match=r"zero_offset_deg"):
        _config(data)


@pytest.fixture(scope="module")
def runs(request):
    """Empty and loaded runs of the sim config's default procedure on an elastic arm and on a rigid one."""
    import yaml
    from conftest import ROOT

    config = _config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()))
    plan = make_plan(config)
    k = np.array([2.0e4, 2.0e4, 2.0e4, 4.0e3, 4.0e3, 4.0e3])  # softer than real: the effect stands out
    out = {"config": config, "k": k}
    for name, fx in (("rigid", PhysicsEffects()), ("elastic", PhysicsEffects(stiffness_nm_per_rad=k)),
                     ("cable", PhysicsEffects(tool_cable=ToolCable((0.3, 0.3, 0.3))))):
        robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=5,
                         noise_nm=0.05, effects=fx)
        empty, _ = record_plan(robot, plan)
        robot.set_payload(TRUTH)
        loaded, _ = record_plan(robot, plan)
        out[name] = (loaded, empty)
    return out


def _estimate(kin):
    def estimate_of(loaded, empty):
        combined, _ = add_combined(subtract_all(loaded, empty))
        return general.solve(combined, kin)
    return estimate_of


def _compensated(kin, run, decl):
    """The agent's recipe for the joints (``evaluation.systematics``): compensate, solve, add the joint terms."""
    prepared = systematics.prepare(*run, decl)
    syst = systematics.evaluate(prepared, kin, decl, terms=[systematics.joint_terms])
    return syst.apply(general.solve(prepared.deltas, kin))


def test_declared_stiffness_compensation_recovers_the_rigid_estimate(runs):
    kin = runs["config"].robot.kinematics
    est = _estimate(kin)
    rigid = est(*runs["rigid"])
    raw = est(*runs["elastic"])
    decl = JointSystematicsConfig(tuple(runs["k"]), 0.1, (np.radians(0.02),) * 6, 0.0, 0.0)
    fixed = _compensated(kin, runs["elastic"], decl)
    err = lambda e: (abs(e.mass_kg - rigid.mass_kg), np.linalg.norm(np.subtract(e.cog_m, rigid.cog_m)))  # noqa: E731
    raw_m, raw_c = err(raw)
    fix_m, fix_c = err(fixed)
    assert raw_m > 1e-3  # the twist costs grams here ...
    assert fix_m < 0.2 * raw_m and fix_c < 0.5 * raw_c + 2e-5  # ... compensated
    # the declared uncertainties widen σ of the compensated estimate, never narrow it, and say so
    certain = _compensated(kin, runs["elastic"], JointSystematicsConfig(tuple(runs["k"]), 0.0, (0.0,) * 6, 0.0, 0.0))
    assert certain.mass_kg == fixed.mass_kg
    assert fixed.mass_std_kg > certain.mass_std_kg
    assert all(f >= c for f, c in zip(fixed.cog_std_m, certain.cog_std_m))
    assert any("elasticity compensated" in n for n in fixed.notes)


def test_tool_cable_check_fails_on_a_strong_cable_and_names_it(runs):
    kin = runs["config"].robot.kinematics
    combined, _ = add_combined(subtract_all(*runs["cable"]))
    bad = cable_check.check(combined, kin)
    assert not bad["passed"] and "cable" in bad["reason"]
    est = general.solve(combined, kin)
    assert abs(est.mass_kg - TRUTH.mass_kg) > 0.010 or np.linalg.norm(np.subtract(est.cog_m, TRUTH.cog_m)) > 0.005
    clean, _ = add_combined(subtract_all(*runs["rigid"]))
    good = cable_check.check(clean, kin)
    assert good["passed"], good
    # the same wrist offsets, as the mass σ the analysis adds for them (systematics.wrist_terms): tens of grams
    # with the cable, under a gram without
    def wrist_sigma_kg(loaded, empty):
        prep = systematics.prepare(loaded, empty, systematics.RIGID)
        syst = systematics.evaluate(prep, kin, systematics.RIGID, terms=[systematics.wrist_terms])
        assert [t.name for t in syst.terms] in ([], ["wrist torques"])
        return float(np.sqrt(syst.covariance()[0, 0])) if syst.terms else 0.0

    with_cable, without = wrist_sigma_kg(*runs["cable"]), wrist_sigma_kg(*runs["rigid"])
    assert with_cable > 0.02 and without < 0.001, (with_cable, without)
