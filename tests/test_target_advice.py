"""`plan --target-std`'s calibration advice (session/target_advice.py): a faster candidate that only its DH-length
term keeps from the target is named, with the calibration on its procedure, only when the stored calibration swept
another procedure (issue 22 item 3)."""

from __future__ import annotations

import dataclasses

import yaml

from conftest import ROOT
from payload_agent.configuration.config import parse_config
from payload_agent.configuration.procedure import load_procedure
from payload_agent.evaluation import design
from payload_agent.evaluation.calibration import (GainCalibration, SweptProcedure, calibration_fingerprint,
                                                  save_calibration)
from payload_agent.recording.state import RobotState
from payload_agent.session import target
from payload_agent.session.target_advice import calibration_advice, kept_out_by_lengths

GRID = [design.Candidate(s, 25, lo, hi, 1, 100, p) for p in ("j2_triple", "j2_pair") for s in (3, 5, 10)
        for lo, hi in ((0, 20), (0, 40))]


def _calibrated_ec66(monkeypatch, tmp_path, procedure: str | None, length_mm: float):
    """sim-ec66 with the DH lengths declared ``length_mm`` uncertain and a stored calibration (hand-made: gains at
    nominal, joints 2-5 fitted) that swept ``procedure`` (None: a file from before the procedure was recorded)."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["robot"]["kinematics"]["length_uncertainty_mm"] = length_mm
    config = parse_config(data, source="configs/sim-ec66.yaml", base_dir=ROOT / "configs")
    swept = None if procedure is None else SweptProcedure(procedure, load_procedure(procedure).fingerprint,
                                                          (0.0, 55.0), 10.0)
    cal = GainCalibration(tuple(config.effort.gains_nm_per_unit), (1, 2, 3, 4), (1.0,) * 6,
                          (0.0, 5e-4, 5e-4, 3e-3, 5e-3, 0.0), 3.0, (0.0, 0.0, 0.08), "sim-ec66", config.effort.unit,
                          calibration_fingerprint(config), str(tmp_path), "2026-01-01", procedure=swept)
    save_calibration(RobotState.for_config(config).ensure(), cal)
    return config


def _choice(config):
    noise, source = target.noise_for(config)
    return noise, source, design.choose(config, 2.0, 1.0, noise, grid=GRID, exhaustive=True)


def test_a_faster_candidate_kept_out_by_its_length_term_is_named_with_the_calibration_on_its_procedure(
        monkeypatch, tmp_path):
    config = _calibrated_ec66(monkeypatch, tmp_path, "paper_bd", 2.0)
    noise, source, choice = _choice(config)
    assert "it swept paper_bd, 0–55°, sweep 10 %" in source
    theta = design.nominal_theta(2.0, (0.0, 0.0, 100.0))
    found = kept_out_by_lengths(config, choice, noise, theta, 2.0, 1.0)
    assert found and len({p.candidate.procedure for p, _ in found}) == len(found)  # one per procedure
    no_lengths = dataclasses.replace(noise, length_std_m=0.0)
    for p, q in found:
        # each misses the target as planned, meets it without the length term, and nothing faster of its procedure
        # does
        assert not p.meets(2.0, 1.0) and q.meets(2.0, 1.0) and q.mass_std_g < p.mass_std_g
        for other in choice.table:
            if (other.usable and other.robot_time_s < p.robot_time_s
                    and other.candidate.procedure == p.candidate.procedure):
                assert not design.predict(config, other.candidate, no_lengths, theta).meets(2.0, 1.0)
    advice = calibration_advice(config, choice, noise, theta, 2.0, 1.0)
    assert "swept paper_bd, 0–55°, sweep 10 %" in advice and "plan again" in advice
    for p, _ in found:
        assert p.candidate.describe() in advice and f"--procedure {p.candidate.procedure}`" in advice


def test_no_advice_when_the_calibration_swept_that_procedure_or_does_not_say_or_no_length_term(monkeypatch, tmp_path):
    theta = design.nominal_theta(2.0, (0.0, 0.0, 100.0))
    config = _calibrated_ec66(monkeypatch, tmp_path / "a", "paper_bd", 2.0)
    noise, _, choice = _choice(config)
    (p, _), *others = kept_out_by_lengths(config, choice, noise, theta, 2.0, 1.0)
    same = _calibrated_ec66(monkeypatch, tmp_path / "b", p.candidate.procedure, 2.0)
    noise, _, choice = _choice(same)
    assert kept_out_by_lengths(same, choice, noise, theta, 2.0, 1.0)
    advice = calibration_advice(same, choice, noise, theta, 2.0, 1.0)
    assert f"--procedure {p.candidate.procedure}`" not in advice  # the calibration's own procedure is not advised
    assert (advice == "") == (not others)
    unknown = _calibrated_ec66(monkeypatch, tmp_path / "c", None, 2.0)
    noise, source, choice = _choice(unknown)
    assert "it swept" not in source and calibration_advice(unknown, choice, noise, theta, 2.0, 1.0) == ""
    exact = _calibrated_ec66(monkeypatch, tmp_path / "d", "paper_bd", 0.0)
    noise, _, choice = _choice(exact)
    assert kept_out_by_lengths(exact, choice, noise, theta, 2.0, 1.0) == []


def test_the_park_advice_names_the_calibrate_command_whose_plan_the_next_plan_offers(monkeypatch, tmp_path):
    """On a fresh sim-ec66 state the plan chooses a slow row (j2_quarter 3 %, 92 s with the approach); the advice names a faster
    candidate as `calibrate ... --park` on its own plan, with keys that make exactly that plan (so the next plan offers
    it as the stored baseline's), with its what-if σ apart from what is predicted now; once that plan is the stored
    one and chosen, no advice."""
    import re

    from payload_agent.calibrate_args import with_procedure, with_speed, with_sweep_and_motion
    from payload_agent.motion.planner import make_plan
    from payload_agent.session.stored_candidate import grid_for
    from payload_agent.session.target_advice import park_advice, parked_what_if
    from test_stored_candidate import _store

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    config = parse_config(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()),
                          source="configs/sim-ec66.yaml", base_dir=ROOT / "configs")
    noise, _ = target.noise_for(config)
    start = [float(v) for v in __import__("numpy").radians(config.simulation.start_deg)]
    theta = design.nominal_theta(2.0, (0.0, 0.0, 100.0))
    slow = design.predict(config, design.Candidate(3, 25, 0, 70, 1, 100, "j2_quarter"), noise, theta, start_q=start)
    assert slow.robot_time_s > 60  # what the plan chooses there (92 s with the approach; P over about 20 %)
    choice = design.Choice(slow, [slow])
    text = park_advice(config, choice, noise, theta, 2.0, 1.0)
    command = re.search(r"--procedure (\S+) --speed-percent (\S+) --sweep-deg (\S+) --travel-speed-percent (\S+) "
                        r"--accel-percent (\S+) --park", text)
    assert command, text
    name, speed, sweep, travel, accel = command.groups()
    cal = with_sweep_and_motion(with_procedure(with_speed(config, float(speed)), name), sweep, float(travel),
                                float(accel))
    advised = next(c for c in design.candidates_for(config) if c.procedure == name and c.speed_percent == float(speed)
                   and (c.sweep_from_deg, c.sweep_to_deg) == tuple(float(v) for v in sweep.split(","))
                   and c.travel_percent == float(travel) and c.accel_percent == float(accel) and c.repetitions == 1)
    seconds = float(re.search(r"(\d+\.\d) s of robot time with no approach", text).group(1))
    assert seconds < choice.best.robot_time_s and seconds == round(design.robot_time_s(design.plan_for(config, advised)), 1)
    what_if = parked_what_if(config, advised, noise, theta)
    assert what_if.meets(2.0, 1.0) and f"{what_if.mass_std_g:.2f} g / {what_if.cog_std_mm:.2f} mm" in text
    assert what_if.approach_s == 0.0
    _store(config, cal)  # what `calibrate` with those keys records: the next plan offers exactly that plan
    stored = [c for c in grid_for(config) if c.stored_baseline]
    assert len(stored) == 1 and make_plan(design.run_config(config, stored[0])).fingerprint() == make_plan(cal).fingerprint()
    chosen = design.Choice(design.predict(config, stored[0], noise, theta, start_q=start), [])
    assert park_advice(config, chosen, noise, theta, 2.0, 1.0) == ""
