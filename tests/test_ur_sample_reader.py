"""The UR driver's own RTDE sample connection against the simulated UR controller over a real socket."""

from __future__ import annotations

import time

import numpy as np
import pytest

from payload_agent.drivers.ur_rtde.driver import SAMPLE_FIELDS
from payload_agent.drivers.ur_rtde.sample_reader import RTDESampleReader
from payload_agent.errors import CommunicationError
from payload_agent.fakes.ur import FakeURController


@pytest.fixture(scope="module")
def ur():
    with FakeURController(time_scale=1.0) as fake:
        yield fake


def test_packages_come_in_the_controllers_order_and_none_is_lost_while_nobody_reads(ur):
    """Half a second without a read: the packages wait in the connection and come, one period apart, after."""
    reader = RTDESampleReader(ur.host, 30004, 500.0, SAMPLE_FIELDS)
    reader.open(2.0)
    try:
        first = reader.read(1.0)
        time.sleep(0.5)
        got = [reader.read(1.0) for _ in range(400)]
    finally:
        reader.close()
    ts = np.array([first[0]] + [g[0] for g in got])
    assert np.all(np.round(np.diff(ts) * 500) == 1)
    ts_, q, cur, i_target, tau_target = got[-1]
    assert all(len(v) == 6 for v in (q, cur, i_target, tau_target))
    assert np.allclose(q, ur.robot.snapshot().q, atol=1e-3)  # standing: the arm's angles


def test_a_recipe_the_controller_refuses_is_named(ur):
    reader = RTDESampleReader(ur.host, 30004, 500.0, [("timestamp", "DOUBLE"), ("actual_qq", "VECTOR6D")])
    with pytest.raises(CommunicationError, match=r"refused the RTDE sample recipe at 500 Hz: actual_qq \(NOT_FOUND\)"):
        reader.open(2.0)
    reader.close()
    fast = RTDESampleReader(ur.host, 30004, 1000.0, SAMPLE_FIELDS)
    with pytest.raises(CommunicationError, match="at 1000 Hz"):
        fast.open(2.0)
    fast.close()


def test_a_closed_connection_and_corrupt_framing_end_the_stream(ur):
    reader = RTDESampleReader(ur.host, 30004, 500.0, SAMPLE_FIELDS)
    reader.open(2.0)
    ur.inject_fault("garbage", mode="framing")
    try:
        with pytest.raises(CommunicationError, match="corrupt"):
            for _ in range(2000):
                reader.read(1.0)
    finally:
        ur.clear_faults()
        reader.close()
    reader = RTDESampleReader(ur.host, 30004, 500.0, SAMPLE_FIELDS)
    reader.open(2.0)
    assert reader.read(1.0) is not None
    assert not reader.lost
    ur.inject_fault("drop_connections")
    with pytest.raises(CommunicationError, match="lost the RTDE sample connection"):
        for _ in range(2000):
            reader.read(1.0)
    assert reader.lost  # the driver then stops over a new connection, not through ur_rtde's reconnecting control
    reader.close()
    ur.clear_faults()
