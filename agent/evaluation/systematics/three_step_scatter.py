"""The torque-gain scatter as the three-step solver feels it: through the calibrated gains of joints 2 and 3.

Why. The three steps read joints 2 and 3 only where they move, so a still joint's gain error at the angle it
stands at (the gear's mesh ripple under load, ``gain_scatter``) reaches them one way only: the drive-gain
calibration's reference run stood at the same angles with the same errors, and its scale of joint j took the share
w_jk of cluster k's error ε_k (``gain_scatter.absorbed_shares``); every row of joint j then carries −w_jk·ε_k, and
the three-step's estimate moves by −w_jk·ε_k·g_j (g_j: its response to a relative gain error of joint j,
``three_step_response.gain_response``). Its mass is the small difference of the torques of joints 2 and 3: a few
per mille of gain error there move it by about as much, relatively.

Measured in the benchmark (realistic + ripple, 10 %, the same noise with the ripple's parts switched off one at a
time; docs/benchmarks.md, session 16): the three-step's ripple error, 11 g rms, is the still joints' mesh ripple
through this path (the moving joints' mesh ripple moves it by 0.1 g rms, the once-per-turn part on every joint by
1.2 g). The general term's clusters (``gain_scatter.measure`` with plain columns) measure ε_k partly against the
calibrated moving rows, which carry −w·ε_k: over 24 payloads ε̂ = 0.69·ε for joint 3 standing at 0° (w = 0.5),
0.94·ε for joint 2 at −90° (w = 0.21), and the three-step's σ carried about 60 % of its ripple error. Here the
clusters of joints 2 and 3 are measured with the calibration's absorption in their columns (−w_jk·Y_gθ̂ on every row
of joint j, ``measure(absorb_joints=...)``), so ε̂_k is the cluster's own error (slopes 1.05 and 1.02; the term's
mean column then predicts the three-step's ripple shift with a slope of 0.92, residual 2.8 g rms of 10.7 g). Its
posterior given the scatter's size (``ScatterTerm.posterior``, τ from the same fit by maximum likelihood) times
−w_jk·g_j goes into the three-step's σ. Nothing is declared: without a calibration, or where the likelihood-ratio
test finds no scatter, the term is zero. The general fits keep the plain columns (their rows are in band with them;
not re-examined).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation.systematics import gain_scatter, three_step_response
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers.fitted import ALL, FittedModel
from payload_agent.types import SweepKey


@dataclass(frozen=True)
class ThreeStepScatter:
    """The scatter's effect on the three-step's θ = [m, m·c]: unit-σ columns and what was measured."""

    along: np.ndarray  # (4, P): θ's response to P unit-σ parameters (the posterior mean, then a root of P)
    scatter: gain_scatter.GainScatter  # the clusters as measured with the calibration's absorption
    shares: dict[str, tuple[int, float]]  # cluster -> (joint, w) of the clusters of joints 2 and 3

    @property
    def note(self) -> str:
        which = ", ".join(f"{lab} {100 * self.scatter.eps[self.scatter.labels.index(lab)]:+.2f} %"
                          for lab in self.shares)
        return (f"three-step solver: the still joints' gain errors the drive-gain calibration carried into joints 2 "
                f"and 3 ({which}, measured with the calibration's share in their columns; scatter "
                f"{100 * self.scatter.tau:.2g} %) in its σ")


def effect(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, model: FittedModel,
           gain_reference: tuple | None, theta3: np.ndarray) -> ThreeStepScatter | None:
    """The scatter's effect on the three-step solver's θ (``theta3``: its θ on ``deltas``); None without a
    calibration, without a scatter beyond noise, or where the calibration absorbed no cluster of joints 2 and 3."""
    if gain_reference is None:
        return None
    gain = None if model.gain_rel_std is None else list(model.gain_rel_std)
    reads = three_step_response.READS_JOINTS
    # the shares first: a calibration that turned joints 2 and 3 took none of their standing angles' errors
    # (``gain_scales.own_scales``, session 24), and the measurement below would repeat the plain one
    sweeps, groups = list(model.sweeps), list(model.groups_of(ALL))
    labels = list(dict.fromkeys(n for n in gain_scatter.clusters(sweeps, groups) if n is not None))
    shares = {c: (j, w) for c, (j, w) in gain_scatter.absorbed_shares(sweeps, groups, labels, gain_reference).items()
              if j in reads and w}
    if not shares:
        return None
    gs = gain_scatter.measure(dict(deltas), kin, gain, model=model, gain_reference=gain_reference,
                              absorb_joints=reads)
    if gs.tau <= 0.0:
        return None
    response = {j: three_step_response.gain_response(deltas, kin, j, theta3) for j in sorted({j for j, _ in
                                                                                               shares.values()})}
    A = np.zeros((4, len(gs.labels)))
    for k, label in enumerate(gs.labels):
        if label in shares:
            j, w = shares[label]
            A[:, k] = -w * response[j]
    cols = gain_scatter.ScatterTerm(gs, list(gs.labels), shares, {}, "", ALL).effect_columns()
    return ThreeStepScatter(A @ cols, gs, shares)


__all__ = ["ThreeStepScatter", "effect"]
