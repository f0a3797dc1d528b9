"""A simulated controller hosted in a process of its own (fakes/hosted.py), seen from the test's side."""

from __future__ import annotations

import time

from benchmarks.fault_matrix import load_sim_config
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.session.simulation import SimulatedCell


def test_a_method_is_called_in_one_round_trip_after_its_first_use_and_a_value_is_asked_every_time(tmp_path):
    """Tests poll ``robot.snapshot()`` every few milliseconds: once the child said it is a method, each call is one
    request, not a question and then the call. The calls still reach the live controller, and a value (the payload
    the test set) is read afresh each time."""
    cell = SimulatedCell(load_sim_config("elite_ec", tmp_path)).start()
    try:
        ctrl = cell.controller
        assert type(ctrl).__name__ == "HostedController"
        sent: list[tuple[str, str]] = []
        send = ctrl._conn.send
        ctrl._conn.send = lambda msg: (sent.append(msg[:2]), send(msg))[1]

        states = [ctrl.robot.snapshot() for _ in range(3)]
        assert sent == [("get", "robot.snapshot")] + [("call", "robot.snapshot")] * 3
        assert all(s.q.shape == (6,) for s in states)
        t1 = ctrl.robot.now()
        time.sleep(0.1)
        assert ctrl.robot.now() > t1  # the child's clock, asked again: not a kept answer

        sent.clear()
        assert ctrl.robot.payload is None
        ctrl.set_payload(PayloadTruth.point(1.5, (0.0, 0.0, 50.0)))
        assert ctrl.robot.payload.mass_kg == 1.5
        assert sent == [("get", "robot.payload"), ("call", "set_payload"), ("get", "robot.payload")]
    finally:
        cell.close()
