"""The connected readiness checks exist once: `run` stops at the first failure, `doctor` reports every one.

A scripted driver (tests/test_driver_template.py's Stub, samples in-process, no protocol) stands for the
controller: the rules are the checks', not a family's.
"""

from __future__ import annotations

import pytest

from conftest import tweak
from payload_agent.configuration.config import parse_config
from payload_agent.errors import DataError, RobotNotReadyError
from payload_agent.session.readiness import (DOCTOR_CHECKS, FAIL, OK, RUN_CHECKS, Probe, every_check,
                                             first_failure)
from payload_agent.types import StreamStats
from test_driver_template import Stub, StubOptions


@pytest.fixture
def config(sim_ec66_data, tmp_path):
    data = tweak(sim_ec66_data, "storage", {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")})
    return parse_config(data, source="test")


def _refusing_stub() -> Stub:
    drv = Stub()
    drv.options = StubOptions(type="stub", allowed=False)
    return drv


def test_run_stops_at_the_first_failure_with_its_error(config):
    with _refusing_stub() as drv:
        seen = []
        with pytest.raises(RobotNotReadyError, match="the stub says no"):
            first_failure(Probe(config, drv), RUN_CHECKS, seen=seen.append)
    assert [(c.name, c.status) for c in seen] == [("identify", OK), ("state", FAIL)]  # nothing after the state


def test_doctor_reports_every_check_past_a_failure(config):
    with _refusing_stub() as drv:
        checks = every_check(Probe(config, drv, stream_window_s=0.2))
    names = {"identify": "identify", "state": "state", "stream": "sample stream", "pose": "kinematic cross-check",
             "payload": "payload setting", "baseline": "stored baseline", "calibration": "drive-gain calibration"}
    assert [c.name for c in checks] == [names[n] for n in DOCTOR_CHECKS]
    status = {c.name: c.status for c in checks}
    assert status["state"] == FAIL and "the stub says no" in checks[1].detail
    assert status["kinematic cross-check"] == "warn"  # no flange pose: an attended run asks instead
    assert status["drive-gain calibration"] == "info"  # none stored: nominal gains


def test_a_ready_robot_passes_runs_checks_and_says_what_it_found(config):
    with Stub() as drv:
        probe = Probe(config, drv)
        checks = first_failure(probe, RUN_CHECKS)
    assert [c.name for c in checks] == ["identify", "state", "drive-gain calibration", "kinematic cross-check"]
    assert probe.info.vendor == "stub" and probe.gains_note is None  # nominal gains: none stored


def test_the_stream_check_judges_the_drivers_own_statistics(config):
    """The doctor's stream line is the driver's StreamStats (the numbers every sweep's manifest keeps)."""
    slow = StreamStats(nominal_period_s=0.005, count=11, first_t=0.0, last_t=0.1, largest_wall_gap_s=0.01)
    with Stub() as drv:
        drv.end_stats = lambda: slow  # 100 Hz against the stub's nominal 200 Hz
        probe = Probe(config, drv, stream_window_s=0.01)
        stream = every_check(probe, ("identify", "stream"))[1]
        with pytest.raises(DataError, match="not good enough"):
            first_failure(probe, ("stream",))
    assert stream.status == FAIL and stream.data["samples"] == 11 and stream.data["rate_hz"] == pytest.approx(100)
    assert "nominal 200 Hz" in stream.detail
