"""How the three-step solver's estimate responds to each systematic term, by finite differences of its inputs.

The general fit's response to a term (``Term.sens[ALL]``) does not describe the three-step solver's: that
one uses four sweeps' moving-joint rows only (joint 2 in pose b, joint 3 in poses b and d), pairs the
joint-2 and joint-3 sweeps at equal link elevation and divides by the mass found first. A constant torque
on the joint-2 sweep goes straight into the mass there, while the general fit spreads it over every row.
So each term gets the three-step's own ∂θ/∂p (θ = [m, m·c]), under the key ``THREE_STEP`` of ``Term.sens``:

- terms that change the data through the whole analysis (joint stiffness, joint zeros) already re-run it
  on shifted sweeps (``compliance.sensitivities``); the context adds the three-step's θ to what that
  re-run returns (``theta``);
- constant torques on named rows (residual friction, wrist torques) are added to those rows of the
  deltas, one label at a time, and the three steps re-run (``offset_response``);
- the torque-gain scatter acts on still joints only, whose rows the three steps do not read, but a drive-gain
  calibration carried a share of it into the gains of joints 2 and 3, which the three steps do read: that
  share times the three-step's response to a gain error of the joint (``gain_response``; the clusters as
  ``three_step_scatter`` measures them);
- a constant torque in the calibration's reference run (the friction a direction asymmetry leaves there, when the
  friction level changed between the baseline and the reference run) is fitted into the gains of joints 2 and 3,
  which the three steps then read (``reference_offset_response``). The three-step's mass comes from the small
  difference of two large joint torques, so a per-mille gain error of one of them moves it by as much as the tool
  run's own residual friction does (docs/benchmarks.md, hard scenario).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.evaluation import reference_shares
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import general, three_step
from payload_agent.solvers.wls import Group
from payload_agent.types import SweepKey

THREE_STEP = three_step.NAME  # the key of the three-step's sensitivities in ``Term.sens``
STEP_NM = 1e-3  # the finite step of a constant torque (the three steps are linear in Δτ but for 1/m)
GAIN_STEP = 1e-4  # the finite step of a relative gain error
READS_JOINTS = (1, 2)  # 0-based: the only rows the three steps read (joint 2 and joint 3)


def theta(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics) -> np.ndarray | None:
    """θ = [m, m·c] of the three-step solver on these deltas, None where it cannot solve them."""
    try:
        est = three_step.solve(dict(deltas), kin)
    except DataError:
        return None
    return np.array([est.mass_kg, *(est.mass_kg * np.asarray(est.cog_m))])


def offset_response(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, sweeps: Sequence[DeltaSweep],
                    groups: Sequence[Group], selector: Callable[[Group, DeltaSweep], "str | None"],
                    labels: Sequence[str], theta0: np.ndarray) -> np.ndarray:
    """(4, P): ∂θ/∂b_k of the three-step solver for a constant torque b_k on the rows ``selector`` names
    ``labels[k]`` (``groups`` of ``sweeps``: the general fit's, which name the rows)."""
    by_name = {d.key.name: d for d in sweeps}
    rows: dict[str, list[tuple[SweepKey, int]]] = {lab: [] for lab in labels}
    for g in groups:
        d = by_name[g.sweep]
        name = selector(g, d)
        if name in rows and g.joint in READS_JOINTS:
            rows[name].append((d.key, g.joint))
    out = np.zeros((4, len(labels)))
    for k, lab in enumerate(labels):
        if not rows[lab]:
            continue
        shifted = dict(deltas)
        for key, j in rows[lab]:
            d = shifted[key]
            dtau = np.array(d.dtau, float)
            dtau[:, j] += STEP_NM
            shifted[key] = replace(d, dtau=dtau)
        th = theta(shifted, kin)
        if th is None:
            raise DataError(f"three-step: not solvable with a {STEP_NM} N·m step on {lab}")
        out[:, k] = (th - theta0) / STEP_NM
    return out


def gain_response(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, joint: int, theta0: np.ndarray) -> np.ndarray:
    """(4,): ∂θ/∂g of the three-step solver for a relative gain error g of ``joint`` (0-based) on every sweep;
    zero for a joint whose rows the three steps do not read."""
    if joint not in READS_JOINTS:
        return np.zeros(4)
    shifted = {}
    for key, d in deltas.items():
        dtau = np.array(d.dtau, float)
        dtau[:, joint] *= 1.0 + GAIN_STEP
        shifted[key] = replace(d, dtau=dtau)
    th = theta(shifted, kin)
    if th is None:
        raise DataError(f"three-step: not solvable with joint {joint + 1}'s gain {GAIN_STEP:g} higher")
    return (th - theta0) / GAIN_STEP


def reference_offset_shares(sweeps: Sequence[DeltaSweep], groups: Sequence[Group],
                            selector: Callable[[Group, DeltaSweep], "str | None"], labels: Sequence[str],
                            reference: tuple, joints: Sequence[int] | None = None) -> dict[int, np.ndarray]:
    """Per calibrated joint j: (P,) ε_jk, the relative gain change the calibration's fit of joint j made per N·m of
    a constant torque on the rows ``selector`` names ``labels[k]`` in its reference run
    (``general.absorbed_length_error`` with the "length derivative" 1_k·θ_refᵀ/|θ_ref|²). Any solver reads it
    through the gains: the tool data are off by −ε_jk·b_k relatively.

    ``joints``: the joint whose two-direction moving rows each label names (the residual-friction term's). With
    them, and a calibration that stored its own response (``reference_shares``), that response is read; else the
    ``sweeps`` and ``groups`` given stand in for the calibration's (right only for the same procedure)."""
    stored = reference_shares.of_reference(reference)
    if stored is not None and joints is not None:
        return stored.friction(sorted(int(j) for j in reference[1]), joints)
    theta_ref = np.asarray(list(reference[0]), float)
    by_name = {d.key.name: d for d in sweeps}
    names = np.repeat(np.array([selector(g, by_name[g.sweep]) for g in groups], dtype=object),
                      [len(g.y) for g in groups])
    Y4 = [replace(g, Y=g.Y[:, :4]) for g in groups]
    unit = theta_ref / float(theta_ref @ theta_ref)
    dY = [np.outer((names == lab).astype(float), unit) for lab in labels]
    return general.absorbed_length_error(list(sweeps), Y4, dY, (theta_ref, sorted(int(j) for j in reference[1])))


def reference_offset_response(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, sweeps: Sequence[DeltaSweep],
                              groups: Sequence[Group], selector: Callable[[Group, DeltaSweep], "str | None"],
                              labels: Sequence[str], reference: tuple, theta0: np.ndarray,
                              joints: Sequence[int] | None = None) -> np.ndarray:
    """(4, P): ∂θ/∂b_k of the three-step solver for a constant torque b_k on the rows ``selector`` names
    ``labels[k]`` in the drive-gain calibration's REFERENCE run (``reference`` = (θ_ref, fitted joints, ...) as in
    ``general.absorbed_length_error``; ``joints`` as in ``reference_offset_shares``).

    The calibration's fit of joint j's scale took the share ε_jk = ⟨Y_jθ_ref, 1_k⟩/⟨Y_jθ_ref, Y_jθ_ref⟩ of b_k
    (the DH lengths' absorption with the "length derivative" 1_k·θ_refᵀ/|θ_ref|², whose product with θ_ref is
    the constant on the named rows): the tool data, scaled by the calibrated gain, are off by −ε_jk·b_k
    relatively. Joints the calibration did not fit, or whose rows the three steps do not read, give zero."""
    out = np.zeros((4, len(labels)))
    eps = reference_offset_shares(sweeps, groups, selector, labels, reference, joints)
    fitted = {int(j) for j in reference[1]}
    response = {j: gain_response(deltas, kin, j, theta0) for j in sorted(fitted & set(READS_JOINTS) & set(eps))}
    for j, resp in response.items():
        out -= np.outer(resp, eps[j])
    return out


__all__ = ["THREE_STEP", "STEP_NM", "GAIN_STEP", "theta", "offset_response", "gain_response",
           "reference_offset_shares", "reference_offset_response"]
