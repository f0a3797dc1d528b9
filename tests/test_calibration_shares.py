"""The drive-gain calibration's own response to its reference run's friction and still-joint gain errors
(``calibration_shares``, stored as ``reference_shares`` in gains.json), and the run terms that read it.

Noise-free offline recordings of sim-ur5e (its YAML's friction): the calibration with a 3 kg reference at
(0, 0, 80) mm on one procedure, the tool run (the YAML's payload) on another, as ``benchmarks.length_errors`` sets
them up. The check of "own" is the calibration's fit itself: its gain scales refitted (``fit_gains_from_deltas``,
what ``calibrate`` runs) on its own sweeps with a constant torque added to a joint's rows, or one standing angle's
rows scaled, against what the run's terms read. Before the stored response the run let its own sweeps stand in for
the calibration's: 1.5× off for the friction, 2× for joint 3's share (docs/benchmarks.md, sessions 17 and 18)."""

from __future__ import annotations

import copy
import dataclasses
import json
from dataclasses import replace

import numpy as np
import pytest

from benchmarks import length_errors
from benchmarks.remedies import calibrated_gains
from payload_agent.errors import DataError
from payload_agent.evaluation import systematics
from payload_agent.evaluation.analyse import prepared_run
from payload_agent.evaluation.calibration import (GainCalibration, fit_from_sweeps, fit_gains_from_deltas,
                                                  load_calibration, save_calibration)
from payload_agent.evaluation.reference_shares import STAND_IN_NOTE, ReferenceShares, both_way_joint, of_reference
from payload_agent.evaluation.systematics import gain_scatter, three_step_response
from payload_agent.fakes.arms import SPECS
from payload_agent.recording.state import RobotState
from payload_agent.solvers import general

REF = "3:0,0,80"
STEP_NM = 0.05  # a constant torque the fit's response is linear in (the fit is linear in the data)


def _recorded(calibrate_procedure: str | None, candidate: str):
    """(bench, the calibration's (loaded, empty) runs, the tool's (loaded, empty) runs): the offline recordings."""
    b = length_errors.bench(calibrate_with=REF, candidate=candidate, calibrate_procedure=calibrate_procedure)
    spec = SPECS["ur5e"]()
    return b, length_errors._record(b, spec, b.cal_plan, b.reference), length_errors._record(b, spec, b.run_plan,
                                                                                               b.truth)


def _pair(recorded):
    """(bench, calibration, the calibration's own deltas, the tool run prepared as a calibrated run prepares it)."""
    b, (loaded, empty), tool_run = recorded
    decl = b.config.robot.joints
    cal = fit_from_sweeps(loaded, empty, b.config, b.reference[0], np.asarray(b.reference[1]) / 1000.0, joints=decl)
    own = systematics.prepare(loaded, empty, decl, None).deltas
    loaded, empty = tool_run
    scaled = [{k: replace(v, effort_nm=v.effort_nm * np.asarray(cal.scale)) for k, v in phase.items()}
              for phase in (loaded, empty)]
    return b, cal, own, prepared_run(*scaled, decl, calibrated_gains(cal, 0.0))[0]


@pytest.fixture(scope="module")
def quarter_then_bd_runs():
    """Recorded once for the file: the cluster test ripples copies of the same runs (they are deterministic)."""
    return _recorded("j2_quarter", "paper_bd:10:0:55")


@pytest.fixture(scope="module")
def quarter_then_bd(quarter_then_bd_runs):
    return _pair(quarter_then_bd_runs)


@pytest.fixture(scope="module")
def bd_then_quarter():
    return _pair(_recorded(None, "j2_quarter:10:0:40"))


def _fit_ratio(b, deltas, fitted) -> np.ndarray:
    """k_j = 1/s_j of the calibration's gain fit on ``deltas`` (the measured/predicted ratio per joint)."""
    m, cog = b.reference
    s, _, _ = fit_gains_from_deltas(deltas, b.config.robot.kinematics, b.config.effort.gains_nm_per_unit, m,
                                    np.asarray(cog) / 1000.0)
    return 1.0 / s[list(fitted)]


def _fit_friction_response(b, cal, own, joint: int) -> np.ndarray:
    """The calibration fit's relative ratio change per N·m on ``joint``'s two-direction moving rows (fitted joints)."""
    base = _fit_ratio(b, own, cal.fitted_joints)
    shifted = {}
    for k, d in own.items():
        dtau = np.array(d.dtau, float)
        if d.key.direction == "both" and d.moving == joint:
            dtau[:, joint] += STEP_NM
        shifted[k] = replace(d, dtau=dtau)
    return (_fit_ratio(b, shifted, cal.fitted_joints) / base - 1.0) / STEP_NM


def _run_reads(b, cal, tool, reference, joints):
    kin = b.config.robot.kinematics
    sweeps = general.select_sweeps(tool.deltas)
    groups = general.build_groups(sweeps, kin)
    eps = three_step_response.reference_offset_shares(sweeps, groups, both_way_joint, [str(j) for j in joints],
                                                      reference, joints)
    names = gain_scatter.clusters(sweeps, groups)
    shares = gain_scatter.absorbed_shares(sweeps, groups, list(dict.fromkeys(n for n in names if n)), reference)
    return eps, shares


def test_the_run_reads_the_calibrations_own_friction_response_not_its_own_sweeps(quarter_then_bd):
    b, cal, own, tool = quarter_then_bd
    assert of_reference(cal.reference) is cal.reference_shares is not None
    j2, j3 = 1, 2
    fit = _fit_friction_response(b, cal, own, j2)
    i2 = list(cal.fitted_joints).index(j2)
    assert fit[i2] < -0.04  # a constant torque on joint 2's rows moves its fitted gain by ~5 % per N·m
    new, _ = _run_reads(b, cal, tool, cal.reference, [j2, j3])
    old, _ = _run_reads(b, cal, tool, cal.reference[:5], [j2, j3])
    assert new[j2][0] == pytest.approx(fit[i2], rel=0.02)
    # the paper_bd tool run standing in: 0.85x (1.5x before the calibration gave standing angles their own scales)
    assert abs(old[j2][0] - fit[i2]) > 0.1 * abs(fit[i2])
    # j2_quarter never sweeps joint 3: the reference run has no joint-3 friction column; the stand-in invented one
    assert np.allclose(_fit_friction_response(b, cal, own, j3), 0.0, atol=1e-9)
    assert new[j3][1] == 0.0 and old[j3][1] < -0.02


def test_the_run_reads_the_calibrations_own_share_of_a_standing_angle(quarter_then_bd):
    b, cal, own, tool = quarter_then_bd
    j3 = 2
    _, new = _run_reads(b, cal, tool, cal.reference, [1])
    _, old = _run_reads(b, cal, tool, cal.reference[:5], [1])
    label = next(c for c in new if c.startswith("j3@0.00"))
    # the fit's own: joint 3's rows where it stands at 0° scaled by 1 + ε, refitted
    base = _fit_ratio(b, own, cal.fitted_joints)
    eps = 1e-3
    scaled = {}
    for k, d in own.items():
        dtau = np.array(d.dtau, float)
        if d.moving != j3 and abs(np.median(d.q[:, j3])) < gain_scatter.SAME_ANGLE_RAD:
            dtau[:, j3] *= 1.0 + eps
        scaled[k] = replace(d, dtau=dtau)
    w_fit = (_fit_ratio(b, scaled, cal.fitted_joints) / base - 1.0)[list(cal.fitted_joints).index(j3)] / eps
    assert w_fit == pytest.approx(1.0, abs=0.01)  # j2_quarter: joint 3 stands at 0° in every sweep
    assert new[label] == (j3, pytest.approx(w_fit, abs=0.01))
    # the paper_bd tool run standing in: none (joint 3 moves there, so a calibration on it fits the standing angle a
    # scale of its own, ``gain_scales.own_scales``; half before session 24)
    assert old[label][1] == 0.0


def test_a_joint_only_the_calibration_swept_gets_its_reference_column(bd_then_quarter):
    b, cal, own, tool = bd_then_quarter
    j3 = 2
    assert cal.reference_friction is not None and cal.reference_friction.of_joint(j3) is not None
    fit = _fit_friction_response(b, cal, own, j3)
    new, _ = _run_reads(b, cal, tool, cal.reference, [1, j3])
    assert new[j3][1] == pytest.approx(fit[list(cal.fitted_joints).index(j3)], rel=0.02) and new[j3][1] < -0.02
    # the residual-friction term with a declared asymmetry: one asymmetry per joint, joint 3's only through the
    # reference run, where the tool run (j2_quarter) has no joint-3 sweep (the last column per joint: the reference
    # run's, ``residual_friction.columns``)
    decl = dataclasses.replace(b.config.robot.joints, friction_asymmetry_std=0.05)
    ctx = systematics.Context.build(tool, b.config.robot.kinematics, decl, None, None, cal.reference)
    new_term = systematics.friction_terms(ctx)[0]
    ctx.gain_reference = cal.reference[:5]
    old_term = systematics.friction_terms(ctx)[0]
    assert len(new_term.std) > len(old_term.std)  # joint 3 in the new term only
    assert np.linalg.norm(new_term.sens[systematics.ALL][:, -1]) > 0  # joint 3's reference-run column
    assert "own fit of its sweeps" in new_term.note and STAND_IN_NOTE in old_term.note


def test_gains_json_round_trip_old_files_and_a_malformed_field(quarter_then_bd, tmp_path):
    b, cal, _, _ = quarter_then_bd
    back = GainCalibration.from_json(json.loads(json.dumps(cal.to_json())))
    assert back.reference_shares is not None
    for field in ("clusters", "friction_rel_per_nm"):  # angles pass through degrees: equal to rounding
        assert np.allclose(getattr(back.reference_shares, field), getattr(cal.reference_shares, field), atol=1e-12)
    assert len(back.reference) == 6 and of_reference(back.reference) is back.reference_shares
    old = cal.to_json()
    del old["reference_shares"]
    older = GainCalibration.from_json(old)  # a file from before: read, the run's own sweeps stand in
    assert older.reference_shares is None and of_reference(older.reference) is None and len(older.reference) == 5
    config = dataclasses.replace(b.config, storage=dataclasses.replace(b.config.storage, state_dir=tmp_path))
    state = RobotState.for_config(config)
    save_calibration(state, cal)
    assert load_calibration(state, config).reference_shares is not None
    for path, value, where in ((("still_clusters", 0, "share"), "x", r"reference_shares\.still_clusters\[0\]"),
                               (("friction_rel_per_nm", 0, "fitted_joint"), 9, r"reference_shares\.friction_rel_per_nm\[0\]"),
                               (("still_clusters",), {"a": 1}, r"reference_shares\.still_clusters must be a list")):
        bad = cal.to_json()
        node = bad["reference_shares"]
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = value
        state.gains_path.write_text(json.dumps(bad), encoding="utf-8")
        with pytest.raises(DataError, match=r"gains\.json: cannot read the drive-gain calibration \(" + where):
            load_calibration(state, config)
    with pytest.raises(ValueError, match="reference_shares must be an object"):
        ReferenceShares.from_json([1, 2])
    # the still clusters' own gain errors (session 24, keepboth): stored exactly, absent in older files (none applied)
    scaled = dataclasses.replace(cal.reference_shares, scales=((1, -np.pi / 2, 0.0072, 0.0006),))
    assert ReferenceShares.from_json(json.loads(json.dumps(scaled.to_json()))).scales == scaled.scales
    assert scaled.own_scale(1, -np.pi / 2 + 5e-4, 1e-3) == (0.0072, 0.0006)
    assert scaled.own_scale(2, -np.pi / 2, 1e-3) is None
    assert "still_cluster_scales" not in cal.reference_shares.to_json() or cal.reference_shares.scales
    assert ReferenceShares.from_json({k: v for k, v in scaled.to_json().items() if k != "still_cluster_scales"}).scales == ()
    with pytest.raises(ValueError, match=r"still_cluster_scales\[0\]"):
        ReferenceShares.from_json({**scaled.to_json(), "still_cluster_scales": [{"joint": 2, "angle_rad": 0.0}]})
    # a never-turning joint's, per sign of its torque (session 26): stored exactly, applied only at the same sign
    signed = dataclasses.replace(scaled, signed_scales=((3, np.pi, 1, 0.016, 0.0002), (3, np.pi, -1, -0.003, 0.00004)))
    assert ReferenceShares.from_json(json.loads(json.dumps(signed.to_json()))).signed_scales == signed.signed_scales
    assert signed.own_scale(3, np.pi - 5e-4, 1e-3, 1) == (0.016, 0.0002)
    assert signed.own_scale(3, np.pi, 1e-3, -1) == (-0.003, 0.00004)
    assert signed.own_scale(3, np.pi, 1e-3, 0) is None  # no torque there: no sign, no correction
    assert ReferenceShares.from_json(scaled.to_json()).signed_scales == ()
    with pytest.raises(ValueError, match=r"still_cluster_signed_scales\[0\]"):
        ReferenceShares.from_json({**signed.to_json(), "still_cluster_signed_scales": [
            {"joint": 4, "angle_rad": 0.0, "torque_sign": 0, "gain_error": 0.0, "std": 0.0}]})


EPS = 0.004  # a gear-ripple-like gain error of joint 3 standing at 0° (the EC66's mesh ripple is up to ±0.7 %)


def _rippled(phase: dict) -> dict:
    """Joint 3's effort ×(1 + EPS) in every sweep where it stands at 0°, as a ripple at that angle does in both
    the empty and the loaded run (it scales the gear torque, so the loaded-minus-empty difference too)."""
    out = {}
    for k, s in phase.items():
        effort = np.array(s.effort_nm, float)
        if abs(np.median(s.q[:, 2])) < gain_scatter.SAME_ANGLE_RAD and np.ptp(s.q[:, 2]) < gain_scatter.SAME_ANGLE_RAD:
            effort[:, 2] *= 1.0 + EPS
        out[k] = replace(s, effort_nm=effort)
    return out


def test_a_cluster_the_calibration_took_whole_is_measured_where_the_tool_run_moves_its_joint(quarter_then_bd_runs):
    """j2_quarter keeps joint 3 at 0° throughout, so its scale took the whole error there (w = 1); a paper_bd run
    moves joint 3, whose calibrated rows then carry −ε while the rows at 0° carry none. The three-step's scatter
    measurement (``measure(absorb_joints=...)``) must give that cluster its absorbed column; it used to leave every
    w = 1 cluster out (right only when the joint never moves in the tool run either)."""
    b, cal_runs, tool_runs = copy.deepcopy(quarter_then_bd_runs)  # j2_quarter's calibration, a paper_bd tool run
    decl, kin = b.config.robot.joints, b.config.robot.kinematics
    loaded, empty = (_rippled(p) for p in cal_runs)
    cal = fit_from_sweeps(loaded, empty, b.config, b.reference[0], np.asarray(b.reference[1]) / 1000.0, joints=decl)
    loaded, empty = (_rippled(p) for p in tool_runs)
    scaled = [{k: replace(v, effort_nm=v.effort_nm * np.asarray(cal.scale)) for k, v in p.items()} for p in (loaded, empty)]
    deltas = prepared_run(*scaled, decl, calibrated_gains(cal, 0.0))[0].deltas
    gs = gain_scatter.measure(dict(deltas), kin, gain_reference=cal.reference, absorb_joints=(1, 2))
    label = next(c for c in gs.labels if c.startswith("j3@0.00"))
    assert cal.reference_shares.share(2, 0.0, gain_scatter.SAME_ANGLE_RAD) == pytest.approx(1.0, abs=0.01)
    assert gs.tau > 0
    assert gs.eps[gs.labels.index(label)] == pytest.approx(EPS, rel=0.1)
