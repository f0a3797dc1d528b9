"""The calibration's per-angle gain errors taken off a tool run's still rows that stand at the same angles.

Why. A strain-wave gear's load-dependent mesh ripple is, on a joint that stands while another sweeps, a gain error
ε of that one standing angle (docs/benchmarks.md, session 24): the same ε in every run that stands there. The
drive-gain calibration fits each such (joint, angle) cluster of a joint that also turns a scale of its own
(``gain_scales.own_scales``), so the joint's gain comes from its moving rows, and stores the cluster's ε̂ against
that gain with its σ (``reference_shares.ReferenceShares.scales``). A tool run that stands at the same angle carries
the same ε on the payload's torque there; ``corrected`` divides those rows' loaded − empty torque by 1 + ε̂, so the
general fit reads them as the calibration did. ``systematics.prepare`` applies it given the calibration's
reference: every consumer of a calibrated run's deltas reads them corrected. The three-step solver reads only moving
rows and keeps the moving-row gains. What stays on a corrected cluster is ε − ε̂, the calibration's σ_ε, which the
torque-gain scatter term carries in place of the scatter's size (``gain_scatter.term``) and the plan predicts
(``planned_scatter``). A calibration stored without the scales corrects nothing.

Which rows: joint j's rows in a sweep where j does not move, when its median angle is within ``TOL_RAD`` of a
stored cluster's; for a joint that never turned in the calibration (``still_joint_scales``, stored per sign of the
reference's torque there) only where the median of the run's own loaded − empty torque there has the same sign: the
simulated gear's load-dependent ripple grows with |τ|, a real one's with the signed τ, and the two agree only where the
sign is the same; a row of the other sign keeps the joint's gain and its error stays in the torque-gain term's τ. 1e-3 rad (0.057°) is 1/31 of the mesh period of a 100-tooth-pair gear (1.8° at 2N·q), so the
ripple's phase moves by at most 0.2 rad inside it, and it is wider than what separates the two runs' angles at the
same commanded pose: the stiffness compensation (τ/k, a few 1e-4 rad between payloads) and the calibrated joint
zeros (a few hundredths of a degree, taken off the tool run's angles and not the calibration's).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation import reference_shares
from payload_agent.types import SweepKey

TOL_RAD = 1e-3  # a tool run's still joint within this of a stored cluster's angle stands there (module docstring)


def matches(sweeps: Mapping[str, DeltaSweep] | list[DeltaSweep], reference: tuple | None,
            tol_rad: float = TOL_RAD) -> dict[tuple[str, int], tuple[float, float]]:
    """(sweep name, still joint 0-based) -> the calibration's (ε̂, σ_ε) of the cluster it stands at; {} without."""
    stored = reference_shares.of_reference(reference)
    if stored is None or not stored.scaled_joints():
        return {}
    out = {}
    for d in (sweeps.values() if isinstance(sweeps, Mapping) else sweeps):
        for j in stored.scaled_joints():
            if j == d.moving:
                continue
            # a never-turning joint's error is stored per sign of its torque: the run's own there (module docstring)
            sign = int(np.sign(np.median(d.dtau[:, j])))
            hit = stored.own_scale(j, float(np.median(d.q[:, j])), tol_rad, sign)
            if hit is not None:
                out[(d.key.name, j)] = hit
    return out


def uncorrected(shares: Mapping[str, tuple[int, float]], sweeps: list[DeltaSweep], groups: list, names: list,
                reference: tuple | None) -> dict[str, tuple[int, float]]:
    """``shares`` (``gain_scatter.absorbed_shares``: cluster -> (joint, w)) without the clusters whose rows ``matches``
    corrects: there the calibration's own scale of the cluster took the place of the joint's gain, whose absorption of
    the cluster's error is then gone with it (what stays is ε − ε̂, on the cluster's rows alone). ``names``: each
    group's cluster name (``gain_scatter.clusters``)."""
    found = matches(sweeps, reference)
    fixed = {name for g, name in zip(groups, names) if (g.sweep, g.joint) in found}
    return {c: v for c, v in shares.items() if c not in fixed}


def corrected(deltas: Mapping[SweepKey, DeltaSweep], reference: tuple | None
              ) -> tuple[dict[SweepKey, DeltaSweep], dict[tuple[str, int], tuple[float, float]]]:
    """``deltas`` with every matched still row's torque divided by 1 + ε̂ (``matches``), and the matches."""
    found = matches({k.name: d for k, d in deltas.items()}, reference)
    return scaled(deltas, found), found


def scaled(deltas: Mapping[SweepKey, DeltaSweep], found: Mapping[tuple[str, int], tuple[float, float]]
           ) -> dict[SweepKey, DeltaSweep]:
    """``deltas`` with the rows of ``found`` (``matches``: (sweep name, joint) -> (ε̂, σ_ε)) divided by 1 + ε̂: the
    same correction on deltas made again from the same run (a finite difference of its angles or torques)."""
    if not found:
        return dict(deltas)
    out = {}
    for key, d in deltas.items():
        factor = np.ones(d.dtau.shape[1])
        for j in range(len(factor)):
            if (key.name, j) in found:
                factor[j] = 1.0 / (1.0 + found[(key.name, j)][0])
        out[key] = d if np.all(factor == 1.0) else replace(d, dtau=np.asarray(d.dtau, float) * factor)
    return out


def note(found: Mapping[tuple[str, int], tuple[float, float]]) -> str:
    """What the result's notes say about the corrected rows."""
    per = {}
    for (_, j), (e, sd) in found.items():
        per.setdefault((j, round(e, 9)), sd)
    text = ", ".join(f"j{j + 1} {100 * e:+.3f}±{100 * sd:.3f} %" for (j, e), sd in sorted(per.items()))
    return (f"still rows standing at the calibration's angles corrected by its per-angle gain errors ({text}; "
            f"{len(found)} (sweep, joint) groups); their remaining error, the calibration's σ, in the torque-gain term")


__all__ = ["TOL_RAD", "matches", "uncorrected", "corrected", "scaled", "note"]
