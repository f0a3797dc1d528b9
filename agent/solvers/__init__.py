"""Payload solvers: turn baseline-subtracted sweeps into mass and centre of mass.

Every solver has one signature, ``solve(deltas, kin, *, gain_rel_std, length_std_m, gain_reference, model)
-> Estimate`` (``model``: the analysis' ``fitted.FittedModel`` of ``deltas``, which a solver built on the
general fit reuses instead of refitting); ``SOLVERS`` maps the CLI name to a ``Solver``. ``general``
(weighted least squares over every loaded joint and sweep) is the default of new configs and carries a
real arm's systematic terms (``evaluation.systematics``); ``three-step`` is the paper's method (both
directions combined where recorded).
"""

from dataclasses import dataclass
from typing import Callable

from payload_agent.solvers import general, three_step
from payload_agent.solvers.fitted import ALL
from payload_agent.solvers.results import Estimate


@dataclass(frozen=True)
class Solver:
    """A solver as the analysis calls it."""

    name: str
    solve: Callable[..., Estimate]  # the common signature above
    # the key of the systematic terms' sensitivities its estimate takes (``evaluation.systematics``): the
    # general fit's (``fitted.ALL``), or its own (the three-step: its name); None: none
    systematics_key: str | None


SOLVERS: dict[str, Solver] = {
    general.NAME: Solver(general.NAME, general.solve, systematics_key=ALL),
    three_step.NAME: Solver(three_step.NAME, three_step.solve, systematics_key=three_step.NAME),
}
