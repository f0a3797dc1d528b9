"""A constant torque on the three-step's rows that is not the friction residual: in its σ as measured (issue 22).

Why. The residual-friction term measures one nuisance offset per moving joint beside the general fit (b̂_j,
``residual_friction.measure``) and uses it where a friction residual of the declared size can leave it
(``residual_friction.consistent``). An offset far beyond that is another torque on those rows (on the hard arm the
arm joints' gear ripple: docs/benchmarks.md, session 23), and the term keeps the declared prior there. For the general
fit that is right: such a torque moves its θ far less than S·b̂ (session 22). The three-step solver reads nothing
but those rows, and a constant on them goes straight into its mass (step 1 is Δτ2 − Δτ3 at equal link elevation):
on the hard arm at 1 % sweeps, the arm joints' ripple alone moved its mass by up to 55 g (case 6, the same noise with
the ripple switched off), where b̂ of joint 2 was −0.23 N·m and not used, and the three-step's σ held 28 g.

What. For the joints whose measured offset the residual-friction term did not use, the three-step's σ gets the
shift S₃·b̂ and its noise: S₃·(b̂b̂ᵀ + C)·S₃ᵀ over those joints (S₃: the three-step's response to a constant torque
on the joint's two-direction rows, ``three_step_response.offset_response``; C: b̂'s covariance). That is the
second moment of the shift given b̂ under a flat prior on the torque: nothing is declared about its size. The
friction residual beneath it keeps its prior in the residual-friction term (a few per cent of this in variance on
the hard arm). The general fits get zero columns. Measured, not taken off θ̂: the general fit's b̂ is one constant
over both poses' sweeps, while the torque the three steps read is on three of them only.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from payload_agent.evaluation.systematics import residual_friction
from payload_agent.evaluation.systematics.terms import Term
from payload_agent.evaluation.systematics.three_step_response import THREE_STEP


NAME = "three-step rows"  # the term's name (``Term.name``)


def terms(post: residual_friction.Posterior, calib: Mapping[str, np.ndarray]) -> list[Term]:
    """The term for the measured offsets ``post`` did not use, as the three-step reads them (``calib``: {fit: (4, 2p)}
    as ``residual_friction.columns`` reads it, the first p columns the tool run's response S per joint of
    ``post.joints``): unit-σ columns S₃·b̂ and S₃·C^½ under ``THREE_STEP``, zero columns under every other key. Empty
    where every measured offset was used or the three-step has no response."""
    m = post.measured
    if m is None or THREE_STEP not in calib:
        return []
    unused = [j for j in post.joints if j in m.joints and not post.used(j)]
    if not unused:
        return []
    S = calib[THREE_STEP][:, [post.joints.index(j) for j in unused]]
    idx = [m.joints.index(j) for j in unused]
    b, C = m.offsets_nm[idx], m.cov[np.ix_(idx, idx)]
    vals, vecs = np.linalg.eigh(0.5 * (C + C.T))
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))
    cols = np.hstack([(S @ b)[:, None], S @ root])
    sens = {k: (cols if k == THREE_STEP else np.zeros_like(cols)) for k in calib}
    found = ", ".join(f"j{j + 1} {b[i]:+.3f}±{np.sqrt(C[i, i]):.3f}" for i, j in enumerate(unused))
    return [Term(NAME, np.ones(cols.shape[1]), sens,
                 f"three-step solver: the offsets beside the fit not read as friction ({found} N·m) are a torque on the "
                 "rows it reads, their effect on it as measured in its σ")]


__all__ = ["NAME", "terms"]
