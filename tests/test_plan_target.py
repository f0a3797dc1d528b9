"""`plan --target-std G,MM` predicts candidate procedures' σ before moving and names the fastest that meets it."""

import json

from conftest import ROOT
from payload_agent import cli


def test_plan_for_a_target_picks_a_procedure_from_the_declared_noise(capsys):
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--target-std", "20,5", "--json"])
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert rc == 0 and doc["target"]["noise_source"].startswith("effort noise and friction declared")
    chosen = doc["target"]["chosen"]
    assert chosen is not None and chosen["mass_std_g"] <= 20 and chosen["cog_std_mm"] <= 5
    assert "chosen:" in out.err


def test_a_malformed_target_names_the_option(capsys):
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--target-std", "2mm"])
    assert rc == 2 and "--target-std" in capsys.readouterr().err


def test_the_candidates_include_other_procedures_and_every_one_passes_the_safety_gate():
    """The joint-2-only procedures are tried beside the configured one, each plan is checked whole by the
    safety gate, and a procedure the gate refuses (its sweep below the floor) is never chosen."""
    import math

    import numpy as np

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.motion.safety import SafetyGate

    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    noise = design.NoiseModel((0.3,) * 6, 0.008, length_std_m=0.5e-3 / math.sqrt(3), joints=config.robot.joints,
                              friction_level_nm=(4.0, 4.0, 3.0, 1.0, 1.0, 0.5))
    grid = [design.Candidate(10, 25, 0, 20, 1, 100, p) for p in ("", "j2_pair", "j2_triple")]
    grid.append(design.Candidate(10, 25, -60, 20, 1, 100, "j2_pair"))  # below the floor: refused
    choice = design.choose(config, 5.0, 3.0, noise, grid=grid, exhaustive=True)
    by = {(p.candidate.procedure, p.candidate.sweep_from_deg): p for p in choice.table}
    assert not by[("j2_pair", -60)].usable and "floor" in " ".join(by[("j2_pair", -60)].problems)
    for (proc, lo), p in by.items():
        if lo == 0:
            assert p.usable, p.problems
            plan = design.plan_for(config, p.candidate)
            cfg = design.with_candidate(config, p.candidate)
            assert SafetyGate(cfg).check(plan, np.asarray(plan.moves[0].target_rad)).ok
            assert {m.sweep.joint for m in plan.sweeps} == ({2, 3} if proc == "" else {2})
    # joint-2 sweeps only: no 90° joint-2 travel to a joint-3 sweep, so less robot time at the same speed
    assert by[("j2_pair", 0)].robot_time_s < 0.7 * by[("", 0)].robot_time_s
    assert choice.best is not None and choice.best.candidate.procedure in ("j2_pair", "j2_triple")


def test_declared_zero_and_friction_terms_raise_the_predicted_sigma():
    """systematics.planned_covariance's terms enter the prediction: more declared uncertainty, more σ."""
    import dataclasses
    import math

    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design

    config = load_config(ROOT / "configs" / "sim-ec66.yaml")
    c = design.Candidate(10, 25, 0, 40, 1, 100, "j2_pair")
    theta = design.nominal_theta(2.0, (40, -25, 70))
    plain = design.NoiseModel((0.3,) * 6, 0.008)
    decl = dataclasses.replace(config.robot.joints, zero_offset_std_rad=(math.radians(0.2),) * 6)
    with_terms = dataclasses.replace(plain, joints=decl, friction_level_nm=(4.0, 4.0, 3.0, 1.0, 1.0, 0.5))
    a, b = design.predict(config, c, plain, theta), design.predict(config, c, with_terms, theta)
    assert b.mass_std_g > a.mass_std_g * 1.05 and b.cog_std_mm > a.cog_std_mm
