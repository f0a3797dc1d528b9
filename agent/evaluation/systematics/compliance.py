"""Joint elasticity and joint zero offsets: compensated where declared, and in σ where uncertain.

A strain-wave gear twists under load: the controller reports the motor-side angle q, the link
stands at q − τ/k. The payload's torque adds its own twist, so the loaded and the empty run put
the arm at different link angles for the same reported angle, and the regressor, evaluated at q,
is slightly wrong. With a declared stiffness k per joint (``robot.kinematics.stiffness_nm_per_rad``
in a robot YAML) ``compensate`` moves every sample to its link angle
q − τ_measured/k before the baseline subtraction, so both runs are matched and modelled at the
angles gravity acts at.

What stays uncertain goes into σ: the declared stiffness has a relative standard uncertainty
(catalogue values are averages) and every joint's zero has a standard uncertainty (encoder
zeroing). Both are systematic: the same on every sample, so no amount of data averages them out.
``sensitivities`` gives their first-order effect: θ̂ is re-solved with each joint's compliance and
zero shifted by a small step; the recipe (``evaluation.systematics``, used by ``analyse``,
``calibrate`` and the benchmark) turns them into terms, Σ = Σ_j σ_j² · (∂θ̂/∂p_j)(∂θ̂/∂p_j)ᵀ.

Pure functions on recorded sweeps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from payload_agent.recording.rundata import SweepData
from payload_agent.solvers.results import Estimate
from payload_agent.types import SweepKey

N_JOINTS = 6
ZERO_STEP_RAD = 1e-4  # finite-difference steps: small against the lever geometry, large against rounding
COMPLIANCE_STEP = 0.05  # relative


@dataclass(frozen=True)
class JointSystematics:
    """What the robot YAML declares about its joints (all optional)."""

    stiffness_nm_per_rad: tuple[float, ...] | None = None  # None or 0 on a joint: rigid, no compensation
    stiffness_rel_std: float = 0.0  # relative standard uncertainty of every declared stiffness
    zero_offset_std_rad: float | Sequence[float] = 0.0  # standard uncertainty of each joint's zero
    # [i][j]: joint j's relative effort change that goes with joint i's angles shifted by 1 rad (a calibration's
    # gain errors correlated with its zero errors: ``evaluation.zero_offsets``); None: none
    zero_effort_coupling: Sequence[Sequence[float]] | None = None

    def compliance(self) -> np.ndarray:
        if self.stiffness_nm_per_rad is None:
            return np.zeros(N_JOINTS)
        k = np.broadcast_to(np.asarray(self.stiffness_nm_per_rad, float), (N_JOINTS,))
        return np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), 0.0)

    def zero_std(self) -> np.ndarray:
        return np.broadcast_to(np.asarray(self.zero_offset_std_rad, float), (N_JOINTS,)).copy()

    @property
    def active(self) -> bool:
        return bool(self.compliance().any() or self.zero_std().any())


Sweeps = Mapping[SweepKey, SweepData]


def zero_covariance(zero_std_rad: float | Sequence[float], corr: Sequence[Sequence[float]] | None = None) -> np.ndarray:
    """The 6×6 covariance of the joint zeros, σ_i·σ_j·ρ_ij (ρ the identity unless a calibration measured them
    jointly: ``JointSystematicsConfig.zero_offset_corr``)."""
    std = np.broadcast_to(np.asarray(zero_std_rad, float), (N_JOINTS,))
    return np.outer(std, std) * (np.eye(N_JOINTS) if corr is None else np.asarray(corr, float))


def principal(cov: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V, σ) with cov[joints][:, joints] = V·diag(σ²)·Vᵀ: independent parameters for a correlated block, so that a
    term of independent parameters (σ, sensitivities A·V) carries the whole covariance."""
    block = cov[np.ix_(joints, joints)]
    lam, V = np.linalg.eigh(block)
    return V, np.sqrt(np.maximum(lam, 0.0))


def compensate(sweeps: Sweeps, compliance_rad_per_nm: Sequence[float],
               zero_shift_rad: Sequence[float] | None = None) -> dict[SweepKey, SweepData]:
    """Every sample moved to its link angle: q − c·τ (+ ``zero_shift_rad``), effort unchanged.

    ``compliance_rad_per_nm`` = 1/k per joint (0: rigid). The measured effort stands for the torque
    through the gear (friction included: it twists the gear too).
    """
    c = np.broadcast_to(np.asarray(compliance_rad_per_nm, float), (N_JOINTS,))
    z = np.zeros(N_JOINTS) if zero_shift_rad is None else np.broadcast_to(np.asarray(zero_shift_rad, float),
                                                                            (N_JOINTS,))
    if not c.any() and not z.any():
        return dict(sweeps)
    return {k: replace(s, q=np.asarray(s.q, float) - np.asarray(s.effort_nm, float) * c + z)
            for k, s in sweeps.items()}


SolveFn = Callable[[dict[SweepKey, SweepData], dict[SweepKey, SweepData]], np.ndarray]


def sensitivities(loaded: Sweeps, empty: Sweeps, decl: JointSystematics, theta_of: SolveFn
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(∂θ/∂(relative compliance)_j, ∂θ/∂zero_j) for every joint: two (6, p) arrays (0 where not declared).

    ``theta_of(loaded, empty)`` runs the caller's whole analysis (subtract, combine, solve) on
    sweeps and returns θ. A zero offset shifts the agent's picture of the arm, not the data's
    timing, so it is applied to both runs alike (with the drive-gain change coupled to it, where a calibration
    measured the two together); a compliance error changes each run by its own torque.
    """
    c = decl.compliance()
    zstd = decl.zero_std()
    base_l, base_e = compensate(loaded, c), compensate(empty, c)
    theta0 = np.asarray(theta_of(base_l, base_e), float)
    p = len(theta0)
    d_c, d_z = np.zeros((N_JOINTS, p)), np.zeros((N_JOINTS, p))
    for j in range(N_JOINTS):
        if c[j] > 0 and decl.stiffness_rel_std > 0:
            cj = c.copy()
            cj[j] *= 1.0 + COMPLIANCE_STEP
            th = theta_of(compensate(loaded, cj), compensate(empty, cj))
            d_c[j] = (np.asarray(th) - theta0) / COMPLIANCE_STEP
        if zstd[j] > 0:
            shift = np.zeros(N_JOINTS)
            shift[j] = ZERO_STEP_RAD
            gain = None if decl.zero_effort_coupling is None else \
                1.0 + ZERO_STEP_RAD * np.asarray(decl.zero_effort_coupling[j], float)
            th = theta_of(_scaled(compensate(loaded, c, shift), gain), _scaled(compensate(empty, c, shift), gain))
            d_z[j] = (np.asarray(th) - theta0) / ZERO_STEP_RAD
    return d_c, d_z


def _scaled(sweeps: Mapping[SweepKey, SweepData], gain: np.ndarray | None) -> dict[SweepKey, SweepData]:
    """Every sample's effort × ``gain`` per joint (None: unchanged)."""
    if gain is None:
        return dict(sweeps)
    return {k: replace(s, effort_nm=np.asarray(s.effort_nm, float) * gain) for k, s in sweeps.items()}


def with_covariance(est: Estimate, cov: np.ndarray, note: str | None = None) -> Estimate:
    """``est`` with a new covariance of θ and the standard deviations derived from it (delta method)."""
    from payload_agent.solvers.wls import cog_with_covariance

    theta = np.array([est.mass_kg, *(est.mass_kg * np.asarray(est.cog_m))])
    _, cov_c = cog_with_covariance(theta, cov[:4, :4])
    notes = list(est.notes) + ([note] if note else [])
    return replace(est, covariance=cov, mass_std_kg=float(np.sqrt(max(cov[0, 0], 0.0))),
                   cog_std_m=tuple(float(np.sqrt(max(v, 0.0))) for v in np.diag(cov_c)), notes=notes)
