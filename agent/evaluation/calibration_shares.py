"""The drive-gain calibration measures its own response to its reference run's friction and still-joint gain errors.

``calibrate`` (``calibration.fit_from_sweeps``) calls ``measure`` on the sweeps it fitted; the result is stored in
gains.json and read by every calibrated run (``reference_shares``, whose docstring says why and what).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation import still_joint_scales
from payload_agent.evaluation.gain_scales import MIN_SIGNAL_TO_NOISE
from payload_agent.evaluation.reference_shares import ReferenceShares, both_way_joint
from payload_agent.evaluation.systematics import gain_scatter, three_step_response
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import general
from payload_agent.types import SweepKey


def measure(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, theta_ref: Sequence[float],
            fitted: Sequence[int], own: Mapping[str, tuple[float, float]] | None = None) -> ReferenceShares:
    """Both responses on the calibration's own ``deltas`` for the joints it ``fitted`` (0-based): the projection the
    run used on its own sweeps (``three_step_response.reference_offset_shares``, ``gain_scatter.absorbed_shares``),
    here on the sweeps the fit was made on. ``own``: the still clusters' own (ε, σ_ε) by cluster name, as the gain
    fit measured them (``zero_offsets.JointGainZeroFit.own``), stored at their joint and angle; a never-turning joint's
    (``still_joint_scales``) also at the sign of the reference's torque there, where its σ_ε is below the scatter's τ̂
    (``still_joint_scales.kept``)."""
    sweeps = general.select_sweeps(dict(deltas))
    groups = general.build_groups(sweeps, kin) if sweeps else []
    reference = (list(theta_ref), tuple(int(j) for j in fitted))
    by_name = {d.key.name: d for d in sweeps}
    joints = sorted({g.joint for g in groups if both_way_joint(g, by_name[g.sweep]) is not None})
    eps = three_step_response.reference_offset_shares(sweeps, groups, both_way_joint, [str(k) for k in joints],
                                                      reference)
    friction = tuple((j, k, float(e[i])) for j, e in sorted(eps.items()) for i, k in enumerate(joints))
    names = gain_scatter.clusters(sweeps, groups)
    labels = list(dict.fromkeys(n for n in names if n is not None))
    angles: dict[str, list[float]] = {}
    for g, name in zip(groups, names):
        if name is not None:
            angles.setdefault(name, []).append(float(np.median(by_name[g.sweep].q[:, g.joint])))
    shares = gain_scatter.absorbed_shares(sweeps, groups, labels, reference)
    clusters = tuple((j, float(np.mean(angles[c])), w) for c, (j, w) in shares.items())
    joint_of = {name: g.joint for g, name in zip(groups, names) if name is not None}
    signed: dict[str, tuple[int, list[float], int]] = {}
    for c in still_joint_scales.signed_clusters(sweeps, groups, theta_ref, MIN_SIGNAL_TO_NOISE):
        if c is not None:
            signed.setdefault(c[0], (c[1], [], c[3]))[1].append(c[2])
    own = still_joint_scales.kept(dict(own or {}), list(signed))
    scales = tuple((joint_of[c], float(np.mean(angles[c])), float(e), float(sd))
                   for c, (e, sd) in own.items() if c in angles)
    signed_scales = tuple((signed[c][0], float(np.mean(signed[c][1])), signed[c][2], float(e), float(sd))
                          for c, (e, sd) in own.items() if c in signed)
    return ReferenceShares(friction, clusters, scales, signed_scales)


__all__ = ["measure"]
