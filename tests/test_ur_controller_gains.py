"""The current-to-torque constants from the UR controller's own target_current / target_moment: the
real ur-rtde driver records them from the simulated UR with every sample, the recorder keeps them in
the sweep CSVs, and a run without a stored calibration is analysed with the fitted constants
(``gains_source`` says so)."""

from __future__ import annotations

import math
import socket
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rtde_control", reason="ur-rtde wheel not installed (CPython 3.11/3.12)")

from conftest import ROOT, tweak  # noqa: E402
from payload_agent.configuration.config import parse_config  # noqa: E402
from payload_agent.drivers.base import MotionLimits, Supervision  # noqa: E402
from payload_agent.drivers.ur_rtde.driver import URRTDEDriver  # noqa: E402
from payload_agent.evaluation.controller_gains import joint_speeds, read_target_signals, run_constants  # noqa: E402
from payload_agent.evaluation.pipeline import run_gains  # noqa: E402
from payload_agent.evaluation.recorded_motion import CONTROLLER_CONSTANT_REL_STD  # noqa: E402
from payload_agent.evaluation.torque_constants import SOURCE, fit_torque_constants  # noqa: E402
from payload_agent.fakes.ur import DEFAULT_GAINS_NM_PER_A, FakeURController  # noqa: E402
from payload_agent.motion.planner import Move  # noqa: E402
from payload_agent.recording.recorder import RunRecorder  # noqa: E402
from payload_agent.types import Sample, SweepKey  # noqa: E402

LIMITS = MotionLimits(max_joint_speed_rad_s=3.0, max_joint_accel_rad_s2=40.0)
# shoulder and elbow (the forearm turns 1.1 rad) through a wide range of gravity torque, both ways
A = (0.0, -0.6, 0.5, -1.5, -1.5, 0.0)
B = (0.0, -2.2, 1.0, -1.5, -1.5, 0.0)
TOL_REL = 0.01  # the fitted constant within 1 % of the simulated controller's own


def _sweep(name: str, target) -> Move:
    return Move(name, "sweep", tuple(target), 1.0, 3.0, SweepKey("p", 2, name, 10.0))


def _movej(fake, target, timeout_s: float = 30.0) -> None:
    """A plain URScript program on the primary port moves the arm (the driver only listens: a move through
    its supervision would make this test about a busy machine's timing)."""
    q = ", ".join(f"{v:.6f}" for v in target)
    with socket.create_connection((fake.host, 30001), timeout=5.0) as sock:
        sock.sendall(f"def sweep():\n  movej([{q}], a=3.0, v=1.0)\nend\n".encode())
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        st = fake.robot.snapshot()
        if not st.moving and np.allclose(st.q, target, atol=1e-3):
            return
        time.sleep(0.02)
    raise AssertionError(f"the simulated arm did not reach {target}")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two phases of two moves each, streamed by the real driver and recorded into a run folder."""
    run_dir = tmp_path_factory.mktemp("ctrl-gains") / "run"
    # the arm starts at A; 3x faster than wall time (the sim-ur5e YAML runs 5x): 1,500 packages a second, of
    # which the fit needs no particular one (each carries its controller time and target signals)
    with FakeURController(q0_rad=A, time_scale=3.0) as fake:
        d = URRTDEDriver(URRTDEDriver.parse_options({"type": "ur_rtde", "host": fake.host}), LIMITS,
                         Supervision(max_stream_gap_s=2.0))
        d.connect()
        rec = RunRecorder(run_dir, {"format": "payload-agent-run/1", "config": {}, "effort_unit": "A"})
        samples: list[Sample] = []

        def sink(s: Sample) -> None:
            samples.append(s)
            rec.sink(s)

        d.start_stream(sink)
        try:
            for phase in ("empty", "loaded"):
                rec.begin_phase(phase)
                for name, target in (("up", B), ("down", A)):
                    rec.begin_sweep(_sweep(name, target))
                    _movej(fake, target)
                    d.wait_sample(2.0, after=time.monotonic())
                    rec.end_sweep("complete")
                rec.end_phase("complete")
        finally:
            d.stop_stream()
            rec.close()
            d.close()
    return run_dir, samples


def test_every_sample_carries_the_controller_target_signals(recorded):
    _, samples = recorded
    assert all(s.target_current is not None and len(s.target_current) == 6 for s in samples)
    assert all(s.target_moment is not None and len(s.target_moment) == 6 for s in samples)
    # the controller's model, not the measured current: the two differ by the friction feed-forward and gain
    i = np.array([s.target_current for s in samples])
    effort = np.array([s.effort for s in samples])
    assert np.ptp(i[:, 1]) > 1.0 and not np.allclose(i, effort, atol=1e-3)


def test_constants_fitted_from_the_stream_match_the_simulated_controller(recorded):
    _, samples = recorded
    t = np.array([s.t_ctrl for s in samples])
    q = np.array([s.q for s in samples])
    keep = np.concatenate([[True], np.diff(t) > 0])
    runs = [(np.array([s.target_current for s in samples])[keep], np.array([s.target_moment for s in samples])[keep],
             joint_speeds(t[keep], q[keep]))]
    k = fit_torque_constants(runs)
    for j in (1, 2):  # shoulder and elbow: determined on this motion
        assert k.determined[j], k.reasons[j]
        assert k.k_nm_per_a[j] == pytest.approx(DEFAULT_GAINS_NM_PER_A[j], rel=TOL_REL)
    # the ratio alone is biased by the friction feed-forward in the target current, as on a real UR
    moving = np.abs(runs[0][2][:, 1]) > 0.3
    ratio = np.median(runs[0][1][moving, 1] / runs[0][0][moving, 1])
    assert abs(ratio / DEFAULT_GAINS_NM_PER_A[1] - 1) > 2 * TOL_REL


def test_the_recorded_csv_keeps_the_target_columns(recorded):
    run_dir, _ = recorded
    sig = read_target_signals(run_dir / "empty" / "p-j2-up.csv")
    assert sig is not None
    t, q, i_target, tau_target = sig
    assert len(t) > 100 and i_target.shape == tau_target.shape == (len(t), 6)
    k = run_constants(run_dir)
    assert k is not None and k.k_nm_per_a[1] == pytest.approx(DEFAULT_GAINS_NM_PER_A[1], rel=TOL_REL)


def _config(tmp_path: Path, gains):
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e.yaml").read_text())
    data = tweak(data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    return parse_config(tweak(data, "effort.gains_nm_per_unit", gains))


def test_without_a_calibration_the_run_uses_the_controller_constants_and_says_so(recorded, tmp_path):
    run_dir, _ = recorded
    nominal = [12.0] * 6  # deliberately off: the fitted joints must not be these
    gains = run_gains(_config(tmp_path, nominal), run_dir)
    assert gains.source.startswith(f"{SOURCE}, joints ") and "2, 3" in gains.source
    for j in (1, 2):
        assert gains.nm_per_unit[j] == pytest.approx(DEFAULT_GAINS_NM_PER_A[j], rel=TOL_REL)
        assert 0.015 <= gains.rel_std[j] < 0.03  # the fit's σ with the declared controller-constant uncertainty
    for j, ok in enumerate(run_constants(run_dir).determined):
        if not ok:
            assert gains.nm_per_unit[j] == 12.0 and gains.rel_std[j] == 0.0 and "nominal" in gains.source
    # the same run given explicit (manifest) gains, as `solve` does: the controller's fit still wins
    assert run_gains(_config(tmp_path, nominal), run_dir, gains=nominal).source == gains.source


def test_before_a_run_the_gains_are_the_stored_baselines_controller_constants(recorded, tmp_path):
    """``plan --target-std`` asks the gains a run started now would use (no run folder yet): without a calibration
    and a stored baseline, the nominal ones (it raised a TypeError before); with a stored baseline recorded with
    the controller's target signals, its constants and their uncertainty, as the run will fit them."""
    import shutil

    from payload_agent.recording.state import RobotState

    run_dir, _ = recorded
    config = _config(tmp_path, [12.0] * 6)
    fresh = run_gains(config, None)  # no baseline: the driver declares the signals, so their declared σ
    assert fresh.rel_std == (CONTROLLER_CONSTANT_REL_STD,) * 6 and fresh.nm_per_unit == (12.0,) * 6
    assert "to be fitted by the run" in fresh.source
    shutil.copytree(run_dir, RobotState.for_config(config).baseline_dir)
    stored = run_gains(config, None)
    assert stored.source == run_gains(config, run_dir).source and stored.source.startswith(SOURCE)
    assert stored.nm_per_unit[1] == pytest.approx(DEFAULT_GAINS_NM_PER_A[1], rel=TOL_REL)
    assert 0.015 <= stored.rel_std[1] < 0.03


def test_the_driver_class_says_whether_it_records_the_target_signals(tmp_path, monkeypatch):
    """The capability is a class attribute read through the driver registry, nothing connected: ur_rtde records
    target_current/target_moment, the other built-in drivers do not. Before any run of a UR (no calibration, no
    stored baseline) the plan's gains are the nominal ones with the constants' declared σ; a driver class that
    does not declare it leaves them nominal, with no σ (what its run will report)."""
    from payload_agent.evaluation.controller_gains import records_controller_targets

    assert records_controller_targets("ur_rtde")
    assert not any(records_controller_targets(name) for name in ("modbus", "elite_ec", "canopen"))
    config = _config(tmp_path, [12.0] * 6)
    assert run_gains(config, None).rel_std == (CONTROLLER_CONSTANT_REL_STD,) * 6
    monkeypatch.setattr(URRTDEDriver, "records_controller_targets", False)
    undeclared = run_gains(config, None)
    assert undeclared.rel_std is None and undeclared.nm_per_unit == (12.0,) * 6 and "nominal" in undeclared.source


def test_a_run_without_target_columns_keeps_the_nominal_gains(tmp_path):
    run_dir = tmp_path / "run"
    rec = RunRecorder(run_dir, {"format": "payload-agent-run/1", "config": {}, "effort_unit": "A"})
    rec.begin_phase("empty")
    rec.begin_sweep(_sweep("up", B))
    for n in range(50):  # a driver without target signals (Elite, Modbus, CANopen)
        rec.sink(Sample(0.002 * n, 0.002 * n, (0.0, -1.0 + 0.01 * n, 1.0, 0.0, 0.0, 0.0), (1.0,) * 6))
    rec.end_sweep("complete")
    rec.end_phase("complete")
    rec.close()
    header = (run_dir / "empty" / "p-j2-up.csv").read_text().splitlines()[0]
    assert "target_current1" not in header
    gains = run_gains(_config(tmp_path, [11.0] * 6), run_dir)
    assert gains.nm_per_unit == (11.0,) * 6 and gains.source.startswith("nominal")
    assert math.isfinite(gains.nm_per_unit[0])
