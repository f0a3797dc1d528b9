"""The drive-gain calibration's own response to DH-length errors (``calibration_lengths``, stored as
``length_response`` in gains.json) and the length term that reads it (``general.length_absorption``).

The calibration sweeps paper_bd (3 %, 5 kg at 60, 0, 80 mm) and the tool run j2_quarter (5 %, 0–20°) with the
simulation's payload, which the agent identifies; one simulated UR5e is exact, the other has its DH lengths off
(seed 2's draw within ±0.5 mm: its flange length d6 +0.45 mm). Both are recorded with the simulation's effort noise,
the same draws, so that the fits' weights are the noise's, as on a real arm."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks import length_errors
from payload_agent.evaluation.calibration import GainCalibration
from payload_agent.fakes.arms import DH_ERROR_STREAM, SPECS
from payload_agent.solvers import general, length_response
from payload_agent.solvers.length_response import LengthResponse


@pytest.fixture(scope="module")
def arms():
    b = length_errors.bench(noise=True)
    exact, cal, deltas = length_errors.identified(b, SPECS["ur5e"]())
    spec = SPECS["ur5e"]().with_dh_errors(np.random.default_rng((2, DH_ERROR_STREAM)), 0.5e-3)
    off, cal_off, _ = length_errors.identified(b, spec)
    return b, exact, cal, off, cal_off, length_errors.arm_errors_m(spec, b.config.robot.kinematics), deltas


def test_the_response_predicts_what_the_length_errors_do_to_the_calibration(arms):
    _, _, cal, _, cal_off, dp, _ = arms
    r = cal.length_response
    assert r is not None and len(r.lengths) == len(dp)
    moved = (np.asarray(cal_off.scale) - cal.scale) / cal.scale
    predicted = np.array(r.scale_rel_per_m).T @ dp
    for j in (1, 2):  # joints 2 and 3 carry the reference's whole lever
        assert abs(moved[j]) > 1e-4
        assert moved[j] == pytest.approx(predicted[j], rel=0.1, abs=2e-5)
    dz = cal_off.zeros.shift_rad() - cal.zeros.shift_rad()
    assert np.max(np.abs(dz)) > np.radians(1e-3)
    assert np.allclose(dz, np.array(r.zero_rad_per_m).T @ dp, rtol=0.1, atol=np.radians(2e-4))


def test_the_run_length_term_with_the_response_predicts_the_arm_and_the_older_rule_does_not(arms):
    b, exact, cal, off, _, dp, _ = arms
    actual = off - exact  # g, mm, mm, mm
    S, to_units = length_errors.predictions(b, cal)
    measured, older = (to_units @ (S[k].T @ dp) for k in ("measured", "absorbed"))
    assert abs(actual[0]) > 0.5 and abs(actual[3]) > 0.1  # the lengths move mass and z measurably
    for i in (0, 3):
        assert abs(actual[i] - measured[i]) < 0.15 * abs(actual[i])
    assert abs(actual[0] - older[0]) > 0.5 * abs(actual[0])  # the tool run's sweeps stood in: mass far off


def test_gains_json_round_trip_and_old_files_without_the_response():
    r = LengthResponse(((0, "d"), (1, "a")), ((0.0, 1.5, -2.0, 0.0, 0.0, 0.0), (0.0,) * 6),
                       ((0.0, 0.1, -0.2, 0.0, 0.0, 0.0), (0.0, 0.3, 0.0, 0.0, 0.0, 0.0)))
    cal = GainCalibration((1.0,) * 6, (1, 2), (1.0, 1.01, 0.99, 1.0, 1.0, 1.0), (0.0, 0.002, 0.002, 0.0, 0.0, 0.0),
                          5.0, (0.06, 0.0, 0.08), "sim-ur5e", "N·m", "0" * 16, "", "2026-11-27T10:00:00+00:00",
                          standing_angles=((1, -1.2),), length_response=r)
    back = GainCalibration.from_json(json.loads(json.dumps(cal.to_json())))
    assert back == cal
    assert length_response.of_reference(back.reference) == r and len(back.reference) == 5
    assert length_response.zero_joints(r) == [1, 2]
    old = cal.to_json()
    del old["length_response"]
    older = GainCalibration.from_json(old)
    assert older.length_response is None and length_response.of_reference(older.reference) is None
    bad = cal.to_json()
    bad["length_response"][0]["length"] = "alpha_rad"
    with pytest.raises(ValueError, match="length_response"):
        GainCalibration.from_json(bad)


def test_the_run_says_when_its_calibration_predates_the_response(arms):
    b, _, cal, _, _, _, deltas = arms
    kin, std = b.config.robot.kinematics, b.config.robot.length_uncertainty_m
    new = general.solve(deltas, kin, length_std_m=std, gain_reference=cal.reference)
    old = general.solve(deltas, kin, length_std_m=std, gain_reference=(cal.reference[0], cal.reference[1]))
    assert not any("predates" in n for n in new.notes)
    assert any("predates its measured response" in n for n in old.notes)
    assert new.mass_std_kg > old.mass_std_kg  # j2_quarter after paper_bd: the older rule took most of the term out
