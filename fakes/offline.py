"""Drive a SimRobot through a plan without sockets or clock thread: fast data for tests and benchmarks.

The samples are the same SimStates the protocol front ends would serve; only the
transport is skipped. Used where thousands of runs are needed (the accuracy
benchmark) or where a test checks a solver against the simulator exactly.
"""

from __future__ import annotations

import numpy as np

from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import Plan, SweepKey
from payload_agent.recording.rundata import SweepData


def step_until_still(robot: SimRobot, settle_ticks: int) -> list:
    """Advance the clock until the current motion ends, then ``settle_ticks`` more; every state."""
    states = []
    while True:
        s = robot.step()
        states.append(s)
        if not s.moving:
            break
    for _ in range(settle_ticks):
        states.append(robot.step())
    return states


def record_plan(robot: SimRobot, plan: Plan, *, torque_scale: np.ndarray | None = None,
                settle_ticks: int = 5) -> tuple[dict[SweepKey, SweepData], float]:
    """Run every move of the plan; return the sweeps (effort in N·m × torque_scale) and the motion time (s)."""
    scale = np.ones(6) if torque_scale is None else np.asarray(torque_scale, float)
    sweeps: dict[SweepKey, SweepData] = {}
    t_start = robot.now()
    for move in plan.moves:
        robot.move_joints(move.target_rad, move.speed_rad_s, move.accel_rad_s2)
        states = step_until_still(robot, settle_ticks)
        if move.sweep is not None:
            t = np.array([s.t for s in states])
            q = np.array([s.q for s in states])
            tau = np.array([s.torque_nm for s in states]) * scale
            sweeps[move.sweep] = SweepData(move.sweep, t, q, tau, f"sim:{move.sweep.name}")
    return sweeps, robot.now() - t_start


def record_wrist_moves(robot: SimRobot, plan: Plan, *, settle_ticks: int = 5) -> tuple[dict, float]:
    """Run every move of the plan; return the wrist moves (name -> WristRecord, effort in N·m) and the motion time."""
    from payload_agent.recording.rundata import WristRecord

    out = {}
    t_start = robot.now()
    for move in plan.moves:
        robot.move_joints(move.target_rad, move.speed_rad_s, move.accel_rad_s2)
        states = step_until_still(robot, settle_ticks)
        if move.wrist is not None:
            out[move.wrist] = WristRecord(move.wrist, np.array([s.t for s in states]), np.array([s.q for s in states]),
                                          np.array([s.torque_nm for s in states]))
    return out, robot.now() - t_start
