"""What constant torques on the still wrist do to θ, measured from the run (a weak tool cable, issue 22).

During every arm sweep the wrist joints 4–6 stand still, at the same angles through all sweeps of a pose. A
weak tool cable or hose puts a constant torque there that the model lacks: a spring wound one way, so the
torques of one tool share a sign and add up in θ along the direction the sweeps determine worst (the
offsets' common part is nearly confounded with m·c). One offset b per (pose, wrist joint)
(``offsets.wrist_joint``) is fitted beside θ; the torques move the plain fit by β = A·b (A:
``offsets.offset_sensitivities``), estimated by β̂ = A·b̂ with covariance D = A·C·Aᵀ. What goes into σ is β̂
shrunk to the size the data show beyond their noise, s²·β̂β̂ᵀ with s² = max(q − r, 0)/q, q = β̂ᵀD⁻¹β̂, r = rank D
(E[q] = r + βᵀD⁻¹β: q − r is the unbiased size; docs/sources.md, noncentral χ²).

Where the data show a torque-gain scatter (``gain_scatter``'s likelihood-ratio test) the fit also carries one
nuisance gain column Y_gθ̂ per (joint, standing angle) of the other still joints (``gain_scatter.clusters``);
elsewhere they would only cost the offsets precision (the weak-cable ablation lost coverage with them).
Load-dependent gear ripple frozen at the angle joint 2 or 3 stands at scales the
payload torque of those rows by a few per mille, which moves θ̂ of a fit with wrist offsets, and the offsets,
nearly confounded with m·c, took up the misfit. In the benchmark's ripple ablation (default procedure,
ripple on joints 1–3 only, no torque on the wrist at all) the offsets-only fit put 8–17 g of "wrist
torques" into the mass σ of 4 of 6 cases against ripple errors of 1–2 g; with the nuisance columns 0–3 g.
(A gain column per wrist row as well, to read wrist ripple as what it is, doubles the wrist parameters;
their noise, and the unfitted joint-6 gain the gain term already counts, then came out as an effect of up
to 11 g on the realistic arm, which has no wrist torque: not done. Gain-like wrist errors are the torque-
gain scatter's.)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation.systematics import gain_scatter, offsets
from payload_agent.solvers.fitted import ALL, FittedModel
from payload_agent.solvers.wls import Group, fit


@dataclass(frozen=True)
class WristTorques:
    """The constant wrist torques the data show, as they move the combined fit's θ."""

    labels: list[str]  # "pose/j<joint>", one per (pose, wrist joint)
    offsets_nm: np.ndarray  # (k,) b̂
    shrink: float  # s: the share of β̂ = A·b̂ the data show beyond noise
    q: float  # β̂ᵀD⁻¹β̂


def columns(sweeps: Sequence[DeltaSweep], groups: Sequence[Group], theta: np.ndarray, nuisance_gains: bool = True,
            gain_reference: tuple | None = None) -> tuple[list[Group], list[str]]:
    """The groups with one offset column per (pose, wrist joint) the still wrist names, then (``nuisance_gains``)
    one nuisance gain column (Y_gθ̂) per (joint, standing angle) of the other still joints that carry payload
    torque.

    ``gain_reference``: the drive-gain calibration the data were scaled with (``GainCalibration.reference``). Its
    reference run stood at the same angles with the same gain errors, and its scale of joint j absorbed the share
    w_jk of cluster k's error (``gain_scatter.absorbed_shares``), so every row of joint j, the moving ones
    included, carries −w_jk·ε_k: the column gets −w_jk·Y_gθ̂ on them. Without that the cluster column measures ε_k
    only relative to the joint's own moving rows, and the moving rows' gain error −Σ_k w_jk·ε_k moves θ̂ and,
    through the wrist rows' level, the offsets or the cable spring's stiffness (docs/benchmarks.md, session 14)."""
    by_name = {d.key.name: d for d in sweeps}
    names = [offsets.wrist_joint(g, by_name[g.sweep]) for g in groups]
    labels = list(dict.fromkeys(n for n in names if n is not None))
    others = [c if nuisance_gains and c is not None and g.joint not in offsets.WRIST_JOINTS
              and np.max(np.abs(g.Y[:, :4] @ theta)) > gain_scatter.MIN_CLUSTER_PEAK_NM else None
              for g, c in zip(groups, gain_scatter.clusters(list(sweeps), list(groups)))]
    nuisance = list(dict.fromkeys(c for c in others if c is not None))
    shares = {} if not nuisance or gain_reference is None else \
        gain_scatter.absorbed_shares(list(sweeps), list(groups), nuisance, gain_reference)
    k = len(labels)
    out = []
    for g, name, other in zip(groups, names, others):
        extra = np.zeros((len(g.y), k + len(nuisance)))
        if name is not None:
            extra[:, labels.index(name)] = 1.0
        if other is not None:
            extra[:, k + nuisance.index(other)] = g.Y[:, :4] @ theta
        for c, (j, w) in shares.items():
            if g.joint == j:
                extra[:, k + nuisance.index(c)] -= w * (g.Y[:, :4] @ theta)
        out.append(replace(g, Y=np.hstack([g.Y, extra])))
    return out, labels


def measure(model: FittedModel, A: np.ndarray, labels: Sequence[str]) -> WristTorques | None:
    """The wrist torques of the run ``model`` fitted, over ``labels`` (the (pose, wrist joint) offsets whose
    combined-fit sensitivities are the columns of ``A``, (4, k)); None when the wrist never stands still."""
    sweeps, groups = list(model.sweeps), list(model.groups)
    nuisance = gain_scatter.of_model(model).tau > 0
    aug, names = columns(sweeps, groups, model.fit(ALL).theta[:4], nuisance)
    if not names:
        return None
    gain = None if model.gain_rel_std is None else list(model.gain_rel_std)
    if nuisance:
        res = model.cached(("wrist offsets beside still-joint gains",), lambda: fit(aug, gain))
    else:  # the same fit as the cable check's
        alone = offsets.fit_offsets(model.deltas, model.kin, offsets.wrist_joint, model=model)
        res, names = alone.result, alone.labels
    idx = [4 + names.index(lab) for lab in labels]
    b = res.theta[idx]
    s, q = offsets.shrink(A, b, res.cov[np.ix_(idx, idx)])
    return WristTorques(list(labels), b, s, q)


def along(b: np.ndarray, sens: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{fit: (4, 1)}: every fit's response to the measured torques (``sens``: {fit: (4, k)})."""
    return {which: A @ b[:, None] for which, A in sens.items()}


__all__ = ["WristTorques", "columns", "measure", "along"]
