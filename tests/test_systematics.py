"""A real arm's systematic errors in the agent's own pipeline (``evaluation.systematics``).

- the robot YAML's keys for them are checked, errors naming the key;
- ``analyse_run`` compensates a declared joint stiffness: on an elastic simulated arm the estimate
  moves toward the truth the test set, and the declared uncertainties widen σ with a note each;
- on a simulated arm with a strong tool cable, the agent's own quality gate fails the cable check
  and names the cable as the likely cause.

Runs are recorded in-process from the physics core (``fakes.offline.record_plan``) and go through
a run folder in the documented format, as ``payload-agent solve`` reads it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from payload_agent.configuration.config import parse_config
from payload_agent.configuration.joint_systematics import DEFAULT_FRICTION_ASYMMETRY_PERCENT
from payload_agent.errors import ConfigError, QualityGateError
from payload_agent.evaluation import cable_check, quality
from payload_agent.evaluation.pipeline import analyse_run
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.effects import PhysicsEffects, ToolCable
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan

from conftest import tweak
from test_segmentation_speeds import write_run

TRUTH = PayloadTruth.point(2.5, (50.0, -30.0, 80.0))
STIFFNESS = [1.5e4, 1.5e4, 1.5e4, 3.0e3, 3.0e3, 3.0e3]  # softer than a real EC66: the twist stands out


# -- the YAML keys ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("path, value, key, fragment", [
    ("robot.kinematics.stiffness_nm_per_rad", [3e4] * 5, "robot.kinematics.stiffness_nm_per_rad", "6"),
    ("robot.kinematics.stiffness_nm_per_rad", [3e4, -1, 3e4, 5e3, 5e3, 5e3], "stiffness_nm_per_rad", ">= 0"),
    ("robot.kinematics.stiffness_nm_per_rad", [30, 30, 30, 5, 5, 5], "stiffness_nm_per_rad[0]", "implausibly soft"),
    ("robot.kinematics.stiffness_uncertainty_percent", 150, "stiffness_uncertainty_percent", "100"),
    ("robot.kinematics.zero_offset_uncertainty_deg", "0.02", "zero_offset_uncertainty_deg", "number"),
    ("robot.kinematics.zero_offset_uncertainty_deg", [0.02, 0.02], "zero_offset_uncertainty_deg", "6"),
    ("robot.friction_asymmetry_percent", -5, "robot.friction_asymmetry_percent", ">= 0"),
    ("robot.friction_change_percent", True, "robot.friction_change_percent", "number"),
    ("robot.tool_cable_fitted", "yes", "robot.tool_cable_fitted", "true (a cable or hose runs to the tool), false"),
    ("robot.tool_cable_fitted", "no", "robot.tool_cable_fitted", "got 'no'"),
    ("robot.tool_cable_fitted", 0, "robot.tool_cable_fitted", "or no value (not declared"),
    ("robot.kinematics.stifness_nm_per_rad", [3e4] * 6, "robot.kinematics.stifness_nm_per_rad", "stiffness_nm_per_rad"),
])
def test_bad_systematics_keys_are_refused_naming_the_key(sim_ec66_data, path, value, key, fragment):
    with pytest.raises(ConfigError) as err:
        parse_config(tweak(sim_ec66_data, path, value), source="sim-ec66.yaml")
    assert key in str(err.value) and fragment in str(err.value), str(err.value)


def test_systematics_keys_and_their_defaults(sim_ec66_data):
    sim_ec66_data["robot"].pop("friction_asymmetry_percent", None)  # the sim config declares its symmetric friction
    joints = parse_config(sim_ec66_data).robot.joints
    assert joints.stiffness_nm_per_rad is None  # rigid unless declared
    assert joints.zero_offset_std_rad == pytest.approx((math.radians(0.02),) * 6)
    assert joints.friction_asymmetry_std == pytest.approx(DEFAULT_FRICTION_ASYMMETRY_PERCENT / 100)
    assert parse_config(tweak(sim_ec66_data, "robot.tool_cable_fitted", True)).robot.joints.tool_cable_fitted is True


def test_the_tool_cable_declaration_has_three_states(sim_ec66_data):
    """``robot.tool_cable_fitted`` (session 26): true (a cable is fitted), false (declared: none is) and absent or empty
    (not declared: the presence test decides) are three different declarations. The shipped sim-ec66 and sim-ur5e
    declare false: their simulated tools have no cable. Fails on main, where false and absent were both False."""
    import yaml

    from conftest import ROOT

    def state(data):
        return parse_config(data).robot.joints.tool_cable_fitted

    sim_ec66_data["robot"].pop("tool_cable_fitted", None)
    assert state(sim_ec66_data) is None
    assert state(tweak(sim_ec66_data, "robot.tool_cable_fitted", None)) is None
    assert state(tweak(sim_ec66_data, "robot.tool_cable_fitted", True)) is True
    none = parse_config(tweak(sim_ec66_data, "robot.tool_cable_fitted", False)).robot.joints
    assert none.tool_cable_fitted is False and none.tool_cable_absent
    assert not parse_config(sim_ec66_data).robot.joints.tool_cable_absent
    for name in ("sim-ec66", "sim-ur5e"):
        data = yaml.safe_load((ROOT / "configs" / f"{name}.yaml").read_text())
        assert not data["simulation"].get("effects", {}).get("tool_cable") and state(data) is False
    data = tweak(sim_ec66_data, "robot.kinematics.stiffness_nm_per_rad", [3e4, 3e4, 3e4, 0, 5e3, 5e3])
    data = tweak(data, "robot.kinematics.zero_offset_uncertainty_deg", 0.05)
    data = tweak(data, "robot.kinematics.stiffness_uncertainty_percent", 20)
    joints = parse_config(data).robot.joints
    assert joints.stiffness_nm_per_rad == (3e4, 3e4, 3e4, 0.0, 5e3, 5e3) and joints.stiffness_rel_std == 0.2
    assert joints.zero_offset_std_rad == pytest.approx((math.radians(0.05),) * 6)


# -- through analyse_run ---------------------------------------------------------------------------------------

def _config(data, tmp, **keys):
    data = dict(data, storage={"state_dir": str(tmp / "state")})  # no stored calibration: nominal gains
    for path, value in keys.items():
        data = tweak(data, path.replace("__", "."), value)
    return parse_config(data, source="sim-ec66.yaml")


def _run(tmp, config, effects: PhysicsEffects, seed: int):
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=seed,
                     noise_nm=0.05, effects=effects)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(TRUTH)
    loaded, _ = record_plan(robot, plan)
    return write_run(tmp / f"run{seed}", config, plan, empty, loaded)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Run folders of the sim config's procedure: an elastic arm, and a rigid arm with a strong tool cable."""
    import yaml
    from conftest import ROOT

    tmp = tmp_path_factory.mktemp("systematics")
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["robot"].pop("friction_asymmetry_percent", None)  # the defaults, as on a real arm
    config = _config(data, tmp)
    elastic = _run(tmp, config, PhysicsEffects(stiffness_nm_per_rad=np.array(STIFFNESS)), seed=3)
    cable = _run(tmp, config, PhysicsEffects(tool_cable=ToolCable((0.3, 0.3, 0.3))), seed=4)
    return {"data": data, "tmp": tmp, "elastic": elastic, "cable": cable}


@pytest.fixture(scope="module")
def analysed(recorded):
    """``analyse_run`` of the recorded runs under the declarations the tests compare."""
    def run(name, **keys):
        return analyse_run(_config(recorded["data"], recorded["tmp"], **keys), recorded[name], solver="general")

    return {
        "undeclared": run("elastic"),  # the defaults: rigid, zero and friction terms on
        "declared": run("elastic", robot__kinematics__stiffness_nm_per_rad=STIFFNESS),
        "exact": run("elastic", robot__kinematics__stiffness_nm_per_rad=STIFFNESS,
                     robot__kinematics__stiffness_uncertainty_percent=0),
        "bare": run("elastic", robot__kinematics__zero_offset_uncertainty_deg=0, robot__friction_asymmetry_percent=0),
        "cable": run("cable"),
    }


def _errors(est):
    return abs(est.mass_kg - TRUTH.mass_kg), float(np.linalg.norm(np.subtract(est.cog_m, TRUTH.cog_m)))


def test_declared_stiffness_is_compensated_in_analyse_run(analysed):
    raw, fixed, certain = analysed["undeclared"], analysed["declared"], analysed["exact"]
    raw_m, raw_c = _errors(raw.primary)
    fix_m, fix_c = _errors(fixed.primary)
    assert raw_m > 0.004  # the gears' twist costs grams here ...
    assert fix_m < 0.3 * raw_m and fix_c <= raw_c + 1e-4  # ... and the declared stiffness gives them back
    assert any("elasticity compensated" in n for n in fixed.primary.notes)
    # its uncertainty widens σ: the same run with the stiffness known exactly reports less
    assert certain.primary.mass_kg == pytest.approx(fixed.primary.mass_kg, abs=1e-12)
    assert fixed.primary.mass_std_kg > certain.primary.mass_std_kg
    assert fixed.quality["passed"], quality.require_passed(fixed)


def test_zero_and_friction_terms_widen_sigma_and_say_so(analysed):
    bare, full = analysed["bare"].primary, analysed["undeclared"].primary
    assert full.mass_kg == bare.mass_kg  # σ terms, not corrections
    assert full.mass_std_kg > bare.mass_std_kg and all(f >= b for f, b in zip(full.cog_std_m, bare.cog_std_m))
    assert any("joint zero uncertainty" in n for n in full.notes)
    assert any("friction direction asymmetry" in n for n in full.notes)
    assert not any("joint zero uncertainty" in n for n in bare.notes)


def test_a_strong_tool_cable_fails_the_agents_gate_naming_the_cable(analysed):
    result = analysed["cable"]
    cable = {c["check"]: c for c in result.quality["checks"]}[cable_check.NAME]
    assert not result.quality["passed"] and not cable["passed"]
    assert "cable" in cable["reason"] and cable["chi2"] > cable["chi2_limit"]
    with pytest.raises(QualityGateError, match="tool cable"):
        quality.require_passed(result)
    # the same check passes on the arm without a cable
    clean = analysed["declared"]
    assert {c["check"]: c for c in clean.quality["checks"]}[cable_check.NAME]["passed"]
