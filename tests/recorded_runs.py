"""Offline recordings for the analysis tests: one simulated robot's empty-flange run, then a run per payload."""

from __future__ import annotations

from payload_agent.fakes.offline import record_plan


def record_runs(robot, plan, *payloads):
    """[empty, loaded with payloads[0], loaded with payloads[1], ...]: each ``plan`` recorded on ``robot``
    (``fakes.offline.record_plan``) after mounting the next payload (``PayloadTruth``), in this order, so the
    runs share the robot's friction state and noise stream as a session's phases do."""
    runs = [record_plan(robot, plan)[0]]
    for payload in payloads:
        robot.set_payload(payload)
        runs.append(record_plan(robot, plan)[0])
    return runs
