"""Whether an identified inertia tensor is known well enough to be given: one rule for every way it is identified.

The tensor about the centre of mass is given only when every element's σ (diagonal and products of
inertia) is at most ``INERTIA_MAX_REL_STD`` of the largest principal moment, i.e. its 95 % interval
within about ±40 % of that moment. Looser (25 % on the diagonal alone, before issue 21's accuracy
work) let a 1.5 kg camera bracket through with an element 59-64 % of its largest moment off
(docs/benchmarks.md, "Inertia from the wrist moves"). The wrist moves' result and an imported
recording's both use it.
"""

from __future__ import annotations

import numpy as np

INERTIA_MAX_REL_STD = 0.20


def uncertainty_problem(inertia: np.ndarray, std: np.ndarray) -> str | None:
    """Why the data do not pin this tensor (3×3 about the CoM, with its elements' σ) down, or None."""
    largest = float(np.max(np.linalg.eigvalsh(0.5 * (inertia + inertia.T))))
    worst = float(np.max(std))
    if worst > INERTIA_MAX_REL_STD * largest:
        i, j = np.unravel_index(int(np.argmax(std)), std.shape)
        return (f"I{'xyz'[i]}{'xyz'[j]} is known only to ±{worst:.2g} kg·m² (1σ), more than "
                f"{100 * INERTIA_MAX_REL_STD:.0f} % of the largest principal moment ({largest:.2g} kg·m²): the tool's "
                "inertial torques are too small for these moves")
    return None
