"""The base's move loop on a scripted driver: what it sends, and when it stops, for each answer of the hooks.

No protocol here (tests/test_driver_conformance.py runs the families); the stub's hooks answer from a
script so each rule of the template shows on its own: a refused start sends no stop, an abort stops
before its reason is read, done clears what this session commanded, a missed target is named.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from payload_agent.configuration.options import option
from payload_agent.drivers.base import DONE, RUNNING, Driver, DriverOptions, MotionLimits, aborted, refused
from payload_agent.drivers.settings import CommandLimits, Supervision
from payload_agent.errors import MotionAbortedError, RobotNotReadyError, SafetyError, SupervisionTrip
from payload_agent.types import ControllerInfo, ControllerState, Sample

LIMITS = MotionLimits(1.0, 5.0)
TARGET = np.full(6, 0.2)


@dataclass(frozen=True, kw_only=True)
class StubOptions(DriverOptions):
    allowed: bool = option(True)


class Stub(Driver):
    """Samples at ``self.q`` every 5 ms; ``_start_move`` / ``_move_status`` answer from ``self.script``."""

    name = "stub"
    options_class = StubOptions

    def __init__(self, start=None, statuses=(), q_at_done=TARGET, supervision=None):
        # generous limits: a loaded machine's pauses must not trip what these tests do not test
        super().__init__(self.options_class(type="stub"), LIMITS,
                         supervision or Supervision(max_stream_gap_s=1.0, max_reply_wait_s=1.0))
        self.effort_unit, self.nominal_period_s = "Nm", 0.005
        self.q = np.zeros(6)
        self.start, self.statuses, self.q_at_done = start, list(statuses), q_at_done
        self.log: list[str] = []

    def _open(self) -> None: ...

    def _close(self) -> None: ...

    def _read_sample(self, timeout_s: float) -> Sample | None:
        time.sleep(0.005)
        return Sample(None, time.monotonic(), tuple(self.q), (0.0,) * 6)

    def identify(self) -> ControllerInfo:
        return ControllerInfo("stub", "stub", "1")

    def state(self) -> ControllerState:
        return ControllerState(self.options.allowed, "" if self.options.allowed else "the stub says no")

    def _start_move(self, target, speed_rad_s, accel_rad_s2):
        self.log.append("move")
        return self.start

    def _move_status(self):
        self.command_ok()  # a polled controller: the reply watchdog runs while the move does
        status = self.statuses.pop(0) if self.statuses else RUNNING
        if status is DONE:
            self.q = np.asarray(self.q_at_done, float)
        return status

    def _stop_command(self) -> bool:
        self.log.append("stop")
        return True


def _run(drv: Stub, timeout_s: float = 5.0) -> None:
    with drv:
        drv.wait_sample(2.0)
        drv.move_joints(TARGET, 0.5, 2.0, timeout_s)


def test_done_at_the_target_returns_and_nothing_of_ours_runs():
    drv = Stub(statuses=[RUNNING, RUNNING, DONE])
    _run(drv)
    assert drv.log == ["move"] and not drv.motion_commanded and drv.stop() is False


def test_a_refused_start_sends_no_stop():
    drv = Stub(start=refused("the program is busy with command 7; nothing was sent"))
    with pytest.raises(MotionAbortedError, match="busy with command 7"):
        _run(drv)
    assert drv.log == ["move"] and not drv.motion_commanded


class DroppingStub(Stub):
    """The link goes down while the move is sent: the start answers "refused" and no sample comes after it."""

    dropped = False

    def _start_move(self, target, speed_rad_s, accel_rad_s2):
        self.dropped = True
        return super()._start_move(target, speed_rad_s, accel_rad_s2)

    def _read_sample(self, timeout_s: float) -> Sample | None:
        if self.dropped:
            time.sleep(timeout_s)
            return None
        return super()._read_sample(timeout_s)


def test_a_refusal_from_a_controller_that_went_silent_is_a_lost_link_and_stops():
    drv = DroppingStub(start=refused("the controller refused the move"))
    with pytest.raises(SupervisionTrip):  # the stream watchdog or the refusal check, whichever sees it first
        _run(drv)
    assert drv.log == ["move", "stop"]
    assert drv.last_stop_report is not None and drv.last_stop_report.acknowledged


def test_an_abort_stops_first_and_then_reads_its_reason():
    drv = Stub()

    def reason():
        assert drv.log[-1] == "stop"  # the stop went out before the reason's round trip
        return "the controller stopped the move: protective stop"

    drv.statuses = [RUNNING, aborted(reason)]
    with pytest.raises(MotionAbortedError, match="protective stop"):
        _run(drv)
    assert drv.log == ["move", "stop"] and not drv.motion_commanded


def test_an_unreadable_abort_reason_still_ends_the_move_as_aborted():
    def gone():
        raise OSError("connection reset")

    drv = Stub(statuses=[aborted(gone)])
    with pytest.raises(MotionAbortedError, match="aborted.*could not be read.*connection reset"):
        _run(drv)
    assert drv.log == ["move", "stop"]


def test_the_timeout_stops_the_arm():
    drv = Stub()  # RUNNING for ever
    with pytest.raises(MotionAbortedError, match="did not finish within 0.2 s"):
        _run(drv, timeout_s=0.2)
    assert drv.log == ["move", "stop"]


def test_done_away_from_the_target_names_the_joint_and_sends_no_stop():
    drv = Stub(statuses=[DONE], q_at_done=TARGET + np.radians([0, 0, 2.0, 0, 0, 0]))
    with pytest.raises(MotionAbortedError, match=r"joint 3 is 2\.000° from the target \(tolerance 0\.1°\)"):
        _run(drv)
    assert drv.log == ["move"]  # the controller had reported it finished: nothing of ours to stop


def test_motion_not_allowed_refuses_before_anything_is_sent():
    drv = Stub()
    drv.options = StubOptions(type="stub", allowed=False)
    with pytest.raises(RobotNotReadyError, match="the stub says no"):
        _run(drv)
    assert drv.log == []


class LimitedOptions(StubOptions):
    command_limits: ClassVar[CommandLimits] = CommandLimits(None, 3.0, "stubclient's move")  # as ur-rtde's moveJ


class LimitedClientStub(Stub):
    """A client library with its own acceleration limit (as ur-rtde's moveJ has)."""

    options_class = LimitedOptions


@pytest.mark.parametrize("target, speed, accel, error, words", [
    (TARGET, 1.5, 2.0, SafetyError, "robot.max_joint_speed_deg_s"),  # the robot's speed limit is 1.0 rad/s
    (TARGET, 0.5, 4.0, SafetyError, "above the 3.0 rad/s² the move command accepts \\(stubclient's move\\)"),
    (np.array([0.2, 0.2, np.nan, 0.2, 0.2, 0.2]), 0.5, 2.0, MotionAbortedError, "not finite"),
    (TARGET, 0.5, -1.0, MotionAbortedError, "acceleration -1.0 is not a positive number"),
])
def test_a_request_beyond_the_limits_or_malformed_is_refused_before_anything_is_sent(target, speed, accel, error,
                                                                                      words):
    drv = LimitedClientStub(statuses=[DONE])
    with drv:
        drv.wait_sample(2.0)
        with pytest.raises(error, match=words):
            drv.move_joints(target, speed, accel, 5.0)
        assert drv.log == [] and not drv.motion_commanded
        drv.move_joints(TARGET, 1.0, 3.0, 5.0)  # at the limits exactly: goes
    assert drv.log == ["move"]


def test_the_reply_watchdog_ends_when_the_controller_reports_done():
    """After DONE the driver stops polling; the stream may still trail the controller while the base waits
    for a sample at the target: that wait is no silent controller."""
    drv = Stub(statuses=[RUNNING, DONE], q_at_done=TARGET - 0.01,
               supervision=Supervision(max_stream_gap_s=1.0, max_reply_wait_s=0.02))
    timer = threading.Timer(0.2, lambda: setattr(drv, "q", TARGET.copy()))  # the stream catches up
    timer.start()
    _run(drv)
    timer.join()
    assert drv.log == ["move"] and drv.last_stop_report is None


class ActivatingStub(Stub):
    """A controller that must be activated (drives powered) before it takes a move; logs when it is."""

    def _activate(self) -> None:
        assert self.supervising  # under the armed supervision: a fault while powering up stops the arm
        self.log.append("activate")


def test_activation_runs_before_the_first_move_and_after_an_abnormal_end_never_at_connect():
    drv = ActivatingStub(statuses=[DONE, DONE])
    with drv:
        drv.wait_sample(2.0)
        drv.state(), drv.identify()
        assert drv.log == []  # connecting and reading (doctor, plan --connect) power nothing
        drv.move_joints(TARGET, 0.5, 2.0, 5.0)
        drv.q = np.zeros(6)
        drv.move_joints(TARGET, 0.5, 2.0, 5.0)
        assert drv.log == ["activate", "move", "move"]  # once: the first move ended normally
        drv.statuses = [aborted("a protective stop")]
        with pytest.raises(MotionAbortedError, match="protective stop"):
            drv.move_joints(np.zeros(6), 0.5, 2.0, 5.0)
        drv.statuses = [DONE]
        drv.q_at_done = np.zeros(6)
        drv.move_joints(np.zeros(6), 0.5, 2.0, 5.0)
        assert drv.log == ["activate", "move", "move", "move", "stop", "activate", "move"]
    drv.statuses, drv.q_at_done = [DONE], TARGET
    _run(drv)  # a new connection activates again
    assert drv.log[-2:] == ["activate", "move"]


def test_a_failed_activation_stops_the_arm_and_sends_no_move():
    class Failing(ActivatingStub):
        def _activate(self) -> None:
            super()._activate()
            raise RobotNotReadyError("joint 2 stayed in SWITCHED ON")

    drv = Failing(statuses=[DONE])
    with pytest.raises(RobotNotReadyError, match="joint 2 stayed"):
        _run(drv)
    assert drv.log == ["activate", "stop"]
