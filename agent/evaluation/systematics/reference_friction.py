"""The friction change of a drive-gain calibration's reference run against its baseline, measured by the calibration.

Why it matters: a Coulomb direction asymmetry a_j leaves a_j·Δ_j in the two-direction average of a run whose
constant friction part changed by Δ_j against the empty baseline. In the calibration's reference run that
leftover is fitted into the gains of the joints it calibrates (joints 2 and 3), and the three-step solver, whose
mass is a small difference of those two joints' torques, reads it through the gains
(``three_step_response.reference_offset_response``); the general fit reads it through the gains as well, by its
response to a relative gain error (``reference_columns``; in tests/test_reference_friction.py a 15 % friction drop
in the reference run moves a 3 kg tool's general mass by 6.5 g). A tool run cannot see the reference run, but ``calibrate``
can: it has the reference run's sweeps in both directions and the baseline. So it measures Δ_j per joint with the
same estimator a tool run uses for its own change (``friction.friction_gaps``, ``friction.coulomb_change``: the
legs' half gap split into a constant and a load-dependent part, the constant part's change pooled over the joint's
sweeps), combines it with the declared prior (``robot.friction_change_percent`` × the baseline's constant part,
the form used before anything was measured) and stores the posterior in gains.json (``reference_friction``).

A tool run's σ (both solvers) then uses that posterior (``change_rms_nm``; a calibration stored without it keeps the
declared form), with ONE asymmetry a_j per joint for both runs (``reference_change``, ``residual_friction``): the reference run's leftover
went into the gains and takes the tool run's alike-signed leftover back out, so the two cancel where both runs
changed alike, and add where they changed apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.evaluation.systematics import friction
from payload_agent.recording.rundata import SweepData
from payload_agent.solvers import general
from payload_agent.types import SweepKey


@dataclass(frozen=True)
class JointChange:
    """One joint's constant-friction change in the reference run against the baseline (N·m)."""

    joint: int  # 0-based
    change: friction.CoulombChange  # measured, declared prior, and the two combined
    baseline_constant_nm: float  # the baseline's constant part (``friction.constant_level``): the prior's scale

    def to_json(self) -> dict[str, Any]:
        c = self.change
        return {"joint": self.joint + 1, "measured_nm": c.measured_nm,
                "measured_std_nm": c.measured_std_nm if math.isfinite(c.measured_std_nm) else None,
                "prior_std_nm": c.prior_std_nm, "mean_nm": c.mean_nm, "std_nm": c.std_nm,
                "baseline_constant_nm": self.baseline_constant_nm, "coulomb_only": c.coulomb_only}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "JointChange":
        std = d.get("measured_std_nm")
        change = friction.CoulombChange(float(d["measured_nm"]), float("inf") if std is None else float(std),
                                        float(d["prior_std_nm"]), float(d["mean_nm"]), float(d["std_nm"]),
                                        bool(d.get("coulomb_only", False)))  # absent: stored before session 16
        if not all(math.isfinite(v) for v in (change.measured_nm, change.prior_std_nm, change.mean_nm, change.std_nm)):
            raise ValueError(f"reference_friction joint {d.get('joint')}: a value is not a finite number")
        return cls(int(d["joint"]) - 1, change, float(d["baseline_constant_nm"]))


@dataclass(frozen=True)
class ReferenceFriction:
    """Per joint, the reference run's constant-friction change against the baseline, as the calibration measured it."""

    change_prior_rel: float  # the declared relative change the measurement was combined with (friction_change_std)
    joints: tuple[JointChange, ...]

    def of_joint(self, joint: int) -> JointChange | None:
        return next((c for c in self.joints if c.joint == joint), None)

    def describe(self) -> str:
        """``j2 -0.031±0.012 N·m, j3 declared ±0.024 N·m``: what the calibration found, joint by joint."""
        parts = []
        for c in self.joints:
            ch = c.change
            parts.append(f"j{c.joint + 1} {ch.measured_nm:+.3f}±{ch.measured_std_nm:.3f} N·m" if ch.measured else
                         f"j{c.joint + 1} declared ±{ch.prior_std_nm:.3f} N·m")
        return ", ".join(parts)

    def to_json(self) -> dict[str, Any]:
        return {"change_prior_percent": 100.0 * self.change_prior_rel, "joints": [c.to_json() for c in self.joints]}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "ReferenceFriction":
        return cls(float(d["change_prior_percent"]) / 100.0, tuple(JointChange.from_json(c) for c in d["joints"]))


def measure(loaded: Mapping[SweepKey, SweepData], empty: Mapping[SweepKey, SweepData],
            deltas: Mapping[SweepKey, DeltaSweep], commands: Mapping | None, change_prior_rel: float
            ) -> ReferenceFriction | None:
    """The reference run's (``loaded``) constant-friction change against the baseline (``empty``) per joint: every
    (pose, moving joint) whose two-direction combination the fit uses (``deltas``) and whose legs both runs show,
    pooled per joint by ``friction.coulomb_change`` with the prior ``change_prior_rel`` × the baseline's constant
    part. ``loaded``/``empty``: the compensated sweeps (``systematics.Prepared``); None where no joint has both."""
    lo, em = friction.friction_gaps(loaded, commands), friction.friction_gaps(empty, commands)
    pairs = sorted({(d.key.pose, d.moving) for d in general.select_sweeps(dict(deltas)) if d.key.direction == "both"}
                   & set(lo) & set(em))
    out = []
    for j in sorted({j for _, j in pairs}):
        mine = [pj for pj in pairs if pj[1] == j]
        constant = friction.constant_level([em[pj] for pj in mine])
        change = friction.coulomb_change([lo[pj] for pj in mine], [em[pj] for pj in mine], change_prior_rel * constant,
                                         change_prior_rel)
        out.append(JointChange(j, change, constant))
    return ReferenceFriction(float(change_prior_rel), tuple(out)) if out else None


def of_reference(reference: Sequence | None) -> ReferenceFriction | None:
    """The measured change a calibration's reference tuple carries (``GainCalibration.reference``, 4th entry)."""
    extra = reference[3] if reference is not None and len(reference) > 3 else None
    return extra if isinstance(extra, ReferenceFriction) else None


def change_rms_nm(reference: Sequence | None, joints: Sequence[int], declared_rel: float,
                  constant_nm: Mapping[int, float]) -> tuple[np.ndarray, str]:
    """Per joint of ``joints`` (0-based), √E[Δ²] of the reference run's constant-friction change (N·m), what the
    direction asymmetry multiplies there: the calibration's measured posterior where it stored one for the joint,
    else the declared form ``declared_rel`` × ``constant_nm[j]`` (the tool run's baseline constant part); and a
    note saying which."""
    found = of_reference(reference)
    out, measured, declared = [], [], []
    for j in joints:
        c = None if found is None else found.of_joint(j)
        if c is None:
            out.append(float(declared_rel) * float(constant_nm[j]))
            declared.append(f"j{j + 1}")
            continue
        out.append(c.change.rms_nm)
        measured.append(f"j{j + 1} {c.change.measured_nm:+.3f}±{c.change.measured_std_nm:.3f}" if c.change.measured
                        else f"j{j + 1} prior ±{c.change.prior_std_nm:.3f}")
    declared_form = f"the declared ±{100 * declared_rel:.3g} % of the baseline's constant part"
    if not measured:
        return np.array(out), f"whose change is {declared_form}"
    note = ("whose change the calibration measured against its baseline (" + ", ".join(measured) + " N·m"
            + (f"; prior ±{100 * found.change_prior_rel:.3g} %" if found.change_prior_rel > 0 else "") + ")")
    if declared:
        note += f", {declared_form} for {', '.join(declared)}"
    return np.array(out), note


def reference_columns(deltas: Mapping[SweepKey, DeltaSweep], kin, sweeps: Sequence[DeltaSweep], groups: Sequence,
                      selector, labels: Sequence[str], reference: tuple, general_fit, three_step_theta,
                      sens: Mapping[str, np.ndarray], joints: Sequence[int] | None = None,
                      eps: Mapping[int, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """``sens`` ({fit: (4, P)} of constant torques on the tool run's rows) with P more columns: the same torques in
    the calibration's reference run, which every solver reads through the calibrated gains (the tool data off by
    −ε_jk·b_k relatively, ``three_step_response.reference_offset_shares``: the calibration's own response where
    gains.json stores it and ``joints`` names each label's joint, else the tool run's rows standing in). The general
    fit's (``ALL``):
    −Σ_j G_j·ε_jᵀ, G_j its response to a relative gain error of joint j (as ``wls.gain_covariance``); the
    three-step's by finite differences (``three_step_response.reference_offset_response``); a pose's own fit gets
    zeros (the gains are common to the poses, which the pose comparison differences). ``eps``: those shares when the
    caller has them already."""
    from payload_agent.evaluation.systematics import three_step_response
    from payload_agent.solvers.fitted import ALL

    out = {which: np.hstack([S, np.zeros_like(S)]) for which, S in sens.items()}
    if eps is None:
        eps = three_step_response.reference_offset_shares(sweeps, groups, selector, labels, reference, joints)
    if ALL in sens and eps:
        inv, w, theta = general_fit.normal_inverse, general_fit.weights, general_fit.theta
        joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
        Y = np.vstack([g.Y for g in groups])
        R = np.zeros((4, len(labels)))
        for j, e in eps.items():
            rows = joint_of_row == j
            R -= np.outer((inv @ (Y[rows].T @ (w[rows] * (Y[rows] @ theta))))[:4], e)
        out[ALL] = np.hstack([sens[ALL], R])
    if three_step_response.THREE_STEP in sens and three_step_theta is not None:
        try:
            A = three_step_response.reference_offset_response(deltas, kin, sweeps, groups, selector, labels,
                                                              reference, three_step_theta, joints)
            out[three_step_response.THREE_STEP] = np.hstack([sens[three_step_response.THREE_STEP], A])
        except DataError:
            pass  # no three-step response to the reference run: its tool-run columns alone, as before
    return out


def reference_change(reference: Sequence | None, joints: Sequence[int], declared_rel: float,
                     constant_nm: Mapping[int, float]) -> tuple[np.ndarray, np.ndarray, str]:
    """(μr, sr, note): per joint of ``joints`` the reference run's change as the calibration measured it (posterior
    mean and std), else zero mean and the declared size (``change_rms_nm``) as the std. ONE direction asymmetry a_j
    acts in both runs (``residual_friction``): the reference run's leftover a_j·Δr_j went into the gains and takes the
    tool run's alike-signed leftover back out, so the two cancel where both runs changed alike and add where they
    changed apart, which two independent parameters cannot say."""
    rms, note = change_rms_nm(reference, joints, declared_rel, constant_nm)
    found = of_reference(reference)
    mu_r, sd_r = np.zeros(len(joints)), np.array(rms, float)
    for k, j in enumerate(joints):
        c = None if found is None else found.of_joint(j)
        if c is not None:
            mu_r[k], sd_r[k] = c.change.mean_nm, c.change.std_nm
    return mu_r, sd_r, note + "; one asymmetry per joint in both runs, with the signs of the measured changes"


__all__ = ["JointChange", "ReferenceFriction", "measure", "of_reference", "change_rms_nm", "reference_columns",
           "reference_change"]
