"""Payload solvers: turn baseline-subtracted sweeps into mass and centre of mass.

Each solver is ``solve(deltas, kinematics) -> Estimate``; SOLVERS maps the CLI name to it.
``general`` (weighted least squares over every loaded joint and sweep) is the default of
new configs; ``three-step`` is the paper's method (both directions combined where recorded).
"""

from payload_agent.solvers import general, three_step

SOLVERS = {
    general.NAME: general.solve,
    three_step.NAME: three_step.solve,
}
