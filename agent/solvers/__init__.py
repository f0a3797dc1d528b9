"""Payload solvers: turn baseline-subtracted sweeps into mass and centre of mass.

Each solver is ``solve(deltas, kinematics) -> Estimate``; SOLVERS maps the CLI name to it.
"""

from payload_agent.solvers import three_step

SOLVERS = {
    three_step.NAME: three_step.solve,
}
