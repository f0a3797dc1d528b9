"""Noise-free offline runs of the benchmark's procedure at 20 % on the simulated EC66 with a load-dependent gear ripple.

Shared by the tests of the drive-gain calibration's per-angle scales (``test_mesh_ripple``, ``test_still_joint_scales``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from benchmarks import cases
from benchmarks.reference import REFERENCE
from payload_agent.fakes.arms import SPECS
from payload_agent.fakes.effects import PhysicsEffects, TorqueRipple
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import FrictionParams, PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot

GEAR_RATIO = 100.0


def recorded(load_ratio: Sequence[float], tool: tuple[float, tuple[float, float, float]], seed: int):
    """(reference run, empty run, config, tool run): the empty flange, the calibration's reference and ``tool`` (kg,
    mm) on one arm whose ripple is ``load_ratio`` (per joint) of the gear torque at the mesh frequency only (no-load and
    once-per-turn parts off), its phases fixed by ``seed``; no noise."""
    proc = cases.Procedure("20", 20.0, cases.SPEED_ROW_TRAVEL, cases.SPEED_ROW_ACCEL, *cases.SWEEP_DEG)
    plan, _, config = cases.plans(proc)
    ripple = TorqueRipple(0.0, tuple(load_ratio), GEAR_RATIO, once_per_rev_fraction=0.0)
    friction = FrictionParams(np.array(cases.COULOMB_NM), np.array(cases.VISCOUS_NM_S_RAD), np.zeros(6))
    robot = SimRobot(SPECS["ec66"](), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=cases.TICK_S,
                     friction=friction, noise_nm=0.0, seed=seed, effects=PhysicsEffects(ripple=ripple))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    ref, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(tool[0], tool[1]))
    tool_run, _ = record_plan(robot, plan)
    return ref, empty, config, tool_run
