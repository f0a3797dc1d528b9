"""A control script uploaded anew counts its async operations from the start again (ur_rtde's
rtde_control.script), and until its first register write the controller's output registers still hold
the previous script's last progress word. The driver must not take that stale word for the new move's
"before" state: the new move would then carry the same operation id and never be seen to finish."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("rtde_control")

from payload_agent.drivers.base import MotionLimits, Supervision  # noqa: E402
from payload_agent.drivers.ur_rtde.driver import URRTDEDriver  # noqa: E402
from payload_agent.fakes.ur import FakeURController  # noqa: E402

HOME = [0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0]
FAR = [0.5, -1.3, 1.3, -1.5, -1.4, 0.3]


def test_each_new_control_script_moves_are_seen_to_finish():
    """Three drivers one after the other, each uploading the script anew (its first move: operation id 1 again),
    on a controller whose script takes 0.3 s before its first register write."""
    limits = MotionLimits(max_joint_speed_rad_s=3.0, max_joint_accel_rad_s2=40.0)
    with FakeURController(time_scale=1.0, script_start_delay_s=0.3) as ur:
        for target in (FAR, HOME, FAR):
            d = URRTDEDriver(URRTDEDriver.parse_options({"type": "ur_rtde", "host": ur.host}), limits, Supervision(max_stream_gap_s=0.5, finish_grace_s=2.0))
            d.connect()
            try:
                d.move_joints(target, 1.0, 3.0, timeout_s=10.0)
            finally:
                d.close()
            assert max(abs(a - b) for a, b in zip(ur.robot.snapshot().q, target)) < 1e-3
