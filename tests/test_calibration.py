"""Drive-gain calibration: recovers the simulator's gain errors and fixes the mass; storage and refusals."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from payload_agent.evaluation.pipeline import analyse_run
from payload_agent.evaluation.calibration import (MAX_SCALE_STD, CalibrationFailed, GainCalibration,
                                                  calibration_fingerprint, effective_gains, fit_gains,
                                                  fit_gains_from_deltas, load_calibration, save_calibration)
from payload_agent.evaluation.gain_scales import fit_joint_scales
from payload_agent.analysis.combine import add_combined
from payload_agent.configuration.config import load_config
from payload_agent.analysis.delta import DeltaSweep, subtract_all
from payload_agent.errors import DataError, QualityGateError
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general
from payload_agent.recording.state import RobotState

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "sim-ec66.yaml"
TORQUE_SCALE = np.array([1.0, 1.03, 0.97, 1.0, 1.0, 1.0])  # what the drives report / true torque
REF_M, REF_C = 2.0, (0.040, -0.025, 0.070)
TOOL_M, TOOL_C = 3.5, (-0.030, 0.050, 0.120)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """One empty run and two loaded runs (reference, tool) of the bidirectional plan at 20 % speed."""
    config = load_config(CONFIG)
    config = dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, speed_percent=20.0,
                                                                       bidirectional=True))
    plan = make_plan(config)
    friction = FrictionParams(np.array([4.0, 4, 3, 1, 1, 0.5]), np.array([8.0, 8, 5, 1, 1, 0.5]))
    robot = SimRobot(SPECS["ec66"](), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008,
                     friction=friction, noise_nm=0.3, seed=11)
    empty, _ = record_plan(robot, plan, torque_scale=TORQUE_SCALE)
    robot.set_payload(PayloadTruth.point(REF_M, [1000 * v for v in REF_C]))
    ref, _ = record_plan(robot, plan, torque_scale=TORQUE_SCALE)
    robot.set_payload(PayloadTruth.point(TOOL_M, [1000 * v for v in TOOL_C]))
    tool, _ = record_plan(robot, plan, torque_scale=TORQUE_SCALE)
    return config, plan, empty, ref, tool


def _deltas(loaded, empty, gains=None):
    """Loaded − empty at the given gains (the SweepData are in N·m at gain 1), with combined sweeps."""
    if gains is not None:
        g = np.asarray(gains)
        loaded = {k: dataclasses.replace(v, effort_nm=v.effort_nm * g) for k, v in loaded.items()}
        empty = {k: dataclasses.replace(v, effort_nm=v.effort_nm * g) for k, v in empty.items()}
    return add_combined(subtract_all(loaded, empty))[0]


def write_run(run_dir: Path, config, empty, loaded, gains) -> Path:
    """A run folder in the documented format (manifest + one CSV per sweep), effort in config units."""
    phases = {}
    for phase, sweeps in (("empty", empty), ("loaded", loaded)):
        entries = []
        for key, sd in sweeps.items():
            rel = f"{phase}/{key.name}.csv"
            path = run_dir / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            rows = np.column_stack([sd.t, sd.t, sd.q, sd.effort_nm / np.asarray(gains)])
            header = "t_ctrl_s,t_recv_s," + ",".join(f"q{i}_rad" for i in range(1, 7)) + "," + \
                     ",".join(f"effort{i}" for i in range(1, 7))
            np.savetxt(path, rows, delimiter=",", header=header, comments="")
            entries.append({"file": rel, "name": key.name, "pose": key.pose, "joint": key.joint,
                            "direction": key.direction, "speed_percent": key.speed_percent,
                            "status": "complete", "samples": len(rows)})
        phases[phase] = {"status": "complete", "sweeps": entries}
    manifest = {"format": "payload-agent-run/1", "robot": config.robot.name, "effort_unit": config.effort.unit,
                "gains_nm_per_unit": list(gains), "phases": phases}
    (run_dir / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return run_dir


def with_state(config, state_dir: Path):
    return dataclasses.replace(config, storage=dataclasses.replace(config.storage, state_dir=state_dir))


def test_fit_recovers_gains_and_fixes_mass(sim):
    config, _, empty, ref, tool = sim
    kin = config.robot.kinematics
    scale, std, fitted = fit_gains_from_deltas(_deltas(ref, empty), kin, np.ones(6), REF_M, REF_C)
    assert {1, 2} <= set(fitted) and 0 not in fitted
    true_scale = 1.0 / TORQUE_SCALE
    for j in (1, 2):
        assert abs(scale[j] / true_scale[j] - 1) < 0.003, (j, scale[j], true_scale[j])
        assert 0 < std[j] < 0.003
        assert abs(scale[j] - true_scale[j]) < 4 * std[j] + 5e-4  # the reported uncertainty is not absurd
    for j in set(range(6)) - set(fitted):
        assert scale[j] == 1.0 and std[j] == 0.0
    nominal = general.solve(_deltas(tool, empty), kin)
    calibrated = general.solve(_deltas(tool, empty, scale), kin, gain_rel_std=std)
    assert abs(nominal.mass_kg / TOOL_M - 1) > 0.01  # the gain errors show up in the mass ...
    assert abs(calibrated.mass_kg / TOOL_M - 1) < 0.005  # ... and calibration removes them
    assert abs(calibrated.mass_kg - TOOL_M) < 4 * calibrated.mass_std_kg


def test_implausible_scale_refused(sim):
    config, _, empty, ref, _ = sim
    with pytest.raises(QualityGateError, match=r"joint 2 would need .* nominal drive gain"):
        # the operator typed 3 kg for the 2 kg reference: every joint would need 1.5x its gain
        fit_gains_from_deltas(_deltas(ref, empty), config.robot.kinematics, np.ones(6), 3.0, REF_C)


def test_wrong_reference_named_even_when_the_scale_is_uncertain(sim):
    """A 3 kg reference typed for the 2 kg one: the scale is ~1.5 whatever its uncertainty, and the
    message blames --known-mass / --known-cog, not the payload's size; the numbers travel with the error."""
    config, _, empty, ref, _ = sim
    rng = np.random.default_rng(0)
    noisy = {k: DeltaSweep(k, d.q, d.dtau + rng.normal(0.0, 3.0, d.dtau.shape), d.speed_rad_s)
             for k, d in _deltas(ref, empty).items()}  # noise enough for a scale uncertainty above 1 %
    with pytest.raises(CalibrationFailed) as info:
        fit_gains_from_deltas(noisy, config.robot.kinematics, np.ones(6), 3.0, REF_C)
    message = str(info.value)
    assert "--known-mass" in message and "--known-cog" in message and "heavier" not in message
    assert "about 2.0" in message  # the mass the measured torque fits
    fits = {f.joint: f for f in info.value.fits}
    assert fits[1].status == "implausible" and fits[1].scale_std > MAX_SCALE_STD
    assert abs(fits[1].scale * TORQUE_SCALE[1] - 1.5) < 0.1
    report = info.value.to_json()
    assert report["reference_mass_kg"] == 3.0 and {j["joint"] for j in report["joints"]} >= {2, 3}
    # the right mass on the same data is not refused for being implausible (since session 24 joint 2's scale comes
    # from its moving rows alone, 1.1 % at this noise: "too uncertain", which is not a wrong reference)
    right = {f.joint: f for f in fit_joint_scales(noisy, config.robot.kinematics, REF_M, REF_C)}
    assert right[1].status != "implausible" and abs(right[1].scale * TORQUE_SCALE[1] - 1) < 0.05


def test_no_reference_mounted_refused(sim):
    config, _, empty, _, _ = sim
    with pytest.raises(QualityGateError):
        fit_gains_from_deltas(_deltas(empty, empty), config.robot.kinematics, np.ones(6), REF_M, REF_C)


def test_run_folder_save_load_and_analysis_uses_calibration(sim, tmp_path):
    config, _, empty, ref, tool = sim
    config = with_state(config, tmp_path / "state")
    gains = np.asarray(config.effort.gains_nm_per_unit)
    ref_dir = write_run(tmp_path / "ref", config, empty, ref, gains)
    cal = fit_gains(config, ref_dir, REF_M, REF_C)
    assert cal.robot == config.robot.name and cal.nominal_fingerprint == calibration_fingerprint(config)
    assert abs(cal.scale[1] * TORQUE_SCALE[1] - 1) < 0.003 and abs(cal.scale[2] * TORQUE_SCALE[2] - 1) < 0.003
    assert np.allclose(cal.gains_nm_per_unit, gains * np.asarray(cal.scale))

    state = RobotState.for_config(config)
    assert load_calibration(state, config) is None
    assert effective_gains(config) == (pytest.approx(gains), None)
    path = save_calibration(state, cal)
    assert path == tmp_path / "state" / config.robot.name / "gains.json"
    assert load_calibration(state, config) == cal
    assert GainCalibration.from_json(cal.to_json()) == cal
    assert cal.standing_angles  # where its joints stood: which still-joint gain errors it absorbed
    old = {k: v for k, v in cal.to_json().items() if k != "standing_angles_rad"}  # a file from before
    assert GainCalibration.from_json(old).standing_angles is None and len(GainCalibration.from_json(old).reference) == 2
    used, note = effective_gains(config)
    assert np.allclose(used, cal.gains_nm_per_unit)
    assert "calibration of" in note and "gains.json" in note and "2.000 kg" in note

    tool_dir = write_run(tmp_path / "tool", config, empty, tool, gains)
    result = analyse_run(config, tool_dir, solver="general")
    assert abs(result.primary.mass_kg / TOOL_M - 1) < 0.005
    assert result.extra["gains_source"] == note
    assert np.allclose(result.extra["gains_nm_per_unit"], cal.gains_nm_per_unit)
    assert result.quality["passed"], result.quality["reasons"]


def test_mismatch_and_unreadable_refused(sim, tmp_path):
    config, *_ = sim
    config = with_state(config, tmp_path / "state")
    state = RobotState.for_config(config)
    nominal = np.asarray(config.effort.gains_nm_per_unit)
    scale = np.array([1, 0.97, 1.03, 1, 1, 1])
    cal = GainCalibration(tuple(nominal * scale), (1, 2), tuple(scale), (0, 0.001, 0.001, 0, 0, 0), REF_M, REF_C,
                          config.robot.name, config.effort.unit, calibration_fingerprint(config), "runs/x",
                          "2026-11-21T10:00:00+00:00")
    save_calibration(state, cal)
    assert load_calibration(state, config) == cal

    other_gains = dataclasses.replace(config, effort=dataclasses.replace(
        config.effort, gains_nm_per_unit=tuple(nominal * 1.1)))
    with pytest.raises(DataError, match=r"gains\.json.*gains_nm_per_unit changed.*calibrate"):
        load_calibration(state, other_gains)
    other_unit = dataclasses.replace(config, effort=dataclasses.replace(config.effort, unit="A"))
    with pytest.raises(DataError, match=r"effort unit 'percent_rated'"):
        effective_gains(other_unit)
    rows = list(config.robot.dh)
    rows[1] = dataclasses.replace(rows[1], a_m=rows[1].a_m + 0.001)
    other_kin = dataclasses.replace(config, robot=dataclasses.replace(config.robot, dh=tuple(rows)))
    with pytest.raises(DataError, match="kinematics"):
        load_calibration(state, other_kin)
    # the calibration run's folder still there: the DH edit itself is named (the mistake to look at)
    run = tmp_path / "cal-run"
    run.mkdir()
    (run / "manifest.json").write_text(json.dumps({"config": {"robot": {"kinematics": {"dh": [
        {"a_mm": 1000 * r.a_m, "d_mm": 1000 * r.d_m, "alpha_deg": math.degrees(r.alpha_rad),
         "offset_deg": math.degrees(r.offset_rad)} for r in config.robot.dh]}}}}))
    save_calibration(state, dataclasses.replace(cal, run_dir=str(run)))
    a2 = 1000 * config.robot.dh[1].a_m
    with pytest.raises(DataError, match=rf"robot\.kinematics\.dh\[1\]\.a_mm {a2:g} then, {a2 + 1:g} now") as info:
        load_calibration(state, other_kin)
    assert "dh[0]" not in str(info.value) and "undo it" in str(info.value)
    save_calibration(state, cal)
    foreign = dataclasses.replace(cal, robot="another-arm")
    save_calibration(state, foreign)
    with pytest.raises(DataError, match="robot 'another-arm'"):
        load_calibration(state, config)

    state.gains_path.write_text("{not json", encoding="utf-8")
    with pytest.raises(DataError, match=r"gains\.json: cannot read"):
        load_calibration(state, config)
