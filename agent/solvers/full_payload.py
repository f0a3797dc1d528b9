"""All ten inertial parameters of a payload from one recorded motion, run once empty and once loaded.

    τ_loaded − τ_empty = W(q, q̇, q̈) · θ + friction change,   θ = [m, m·c, I_flange]     (paper eq. 29)

W is the payload's Newton–Euler regressor (``solvers.regressor.payload_regressor``); q̇ and q̈
come from the recorded angles (Savitzky–Golay, ``solvers.dynamic.derivatives``), because a
controller's own velocity is filtered differently and its acceleration is not recorded at all.
The arm's own dynamics cancel in the difference; friction does not quite (it depends on the
load and drifts with temperature), so each joint used gets a Coulomb and a viscous change
column, and its samples near zero speed, where sign(q̇) is unsure, are left out of its rows.

The fit is ``solvers.wls.fit``: weights per joint, autocorrelation-robust covariance, and the
drive-gain uncertainty of each joint propagated into the covariance. Only joints with a
usable gain enter (``gains_nm_per_unit`` None for a joint leaves it out).

The inertia comes out about the flange origin; the result states it about the centre of
mass (parallel-axis theorem) with its standard uncertainties from the same covariance
(delta method), and says when the data alone give a tensor that is not physically possible
(not positive definite, or a principal moment larger than the other two together).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers.dynamic import MOVING_RANGE_RAD, SG_ORDER, SG_WINDOW_S, derivatives, joint_groups
from payload_agent.solvers.regressor import payload_regressor
from payload_agent.solvers.wls import cog_with_covariance, fit

NAME = "full-payload"
PARAMS = ("m", "m*cx", "m*cy", "m*cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
_I_INDEX = ((4, 5, 6), (5, 7, 8), (6, 8, 9))  # θ index of each tensor element


@dataclass(frozen=True)
class FullPayload:
    """The fitted payload: θ and its covariance, and the forms a user reads."""

    theta: np.ndarray  # (10,) SI, inertia about the flange origin in flange axes
    cov: np.ndarray  # (10, 10)
    joints: tuple[int, ...]  # 0-based joints whose torques entered
    residual_rms_nm: dict[str, float]
    samples: dict[str, int]
    condition_number: float
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def mass_kg(self) -> float:
        return float(self.theta[0])

    @property
    def mass_std_kg(self) -> float:
        return float(np.sqrt(max(self.cov[0, 0], 0.0)))

    def cog(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre of mass (m, flange axes) and its 3×3 covariance."""
        return cog_with_covariance(self.theta[:4], self.cov[:4, :4])

    def inertia_com(self) -> tuple[np.ndarray, np.ndarray]:
        """Inertia tensor about the centre of mass (kg·m², flange axes) and the σ of each element."""
        def tensor(th: np.ndarray) -> np.ndarray:
            m, mc = th[0], th[1:4]
            io = np.array([[th[i] for i in row] for row in _I_INDEX])
            c = mc / m
            return io - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))

        base = tensor(self.theta)
        J = np.zeros((9, 10))
        for k in range(10):
            step = 1e-6 * max(abs(self.theta[k]), 1e-3)
            th = self.theta.copy()
            th[k] += step
            J[:, k] = (tensor(th) - base).ravel() / step
        var = np.einsum("ij,jk,ik->i", J, self.cov, J)
        return base, np.sqrt(np.maximum(var, 0.0)).reshape(3, 3)


def consistency_problem(inertia: np.ndarray) -> str | None:
    """Why an inertia tensor about the centre of mass is not physically possible, or None."""
    moments = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    if moments[0] <= 0:
        return f"not positive definite (principal moments {', '.join(f'{v:.3g}' for v in moments)} kg·m²)"
    if moments[2] > moments[0] + moments[1] * (1 + 1e-9):
        return "a principal moment exceeds the sum of the other two (triangle inequality)"
    return None


def solve(t: np.ndarray, q: np.ndarray, dtau_effort: np.ndarray, kin: Kinematics,
          gains_nm_per_unit: Sequence[float | None], gain_rel_std: Sequence[float] | None = None, *,
          friction: bool = True, sg_window_s: float = SG_WINDOW_S, sg_order: int = SG_ORDER) -> FullPayload:
    """θ from loaded − empty effort along one motion on an even time grid ``t``.

    ``dtau_effort``: (n, 6) effort difference in the recording's unit; ``gains_nm_per_unit``:
    per joint, None to leave the joint out; ``gain_rel_std``: their relative standard uncertainty.
    """
    joints = tuple(j for j, g in enumerate(gains_nm_per_unit) if g is not None and g > 0)
    if not joints:
        raise DataError("full payload: no joint has a usable current-to-torque constant")
    qs, qd, qdd = derivatives(t, q, sg_window_s, sg_order)
    moving = [j for j in joints if np.ptp(q[:, j]) > MOVING_RANGE_RAD] if friction else []
    dtau_nm = np.column_stack([dtau_effort[:, j] * (g if g is not None else 0.0) for j, g in enumerate(gains_nm_per_unit)])
    groups = joint_groups(payload_regressor(kin, qs, qd, qdd), qd, dtau_nm, joints, moving, "motion", min_rows=20)
    if not groups:
        raise DataError("full payload: no joint's torque depends on the payload along this motion")
    rel = None
    if gain_rel_std is not None:
        rel = [gain_rel_std[j] if j in joints else 0.0 for j in range(len(gains_nm_per_unit))]
    res = fit(groups, rel)
    theta, cov = res.theta[:10], res.cov[:10, :10]
    if not theta[0] > 0:
        raise DataError(f"full payload: identified mass {theta[0]:.4f} kg is not positive; is the load mounted in "
                        "the loaded recording, and are the files given the right way round?")
    notes = []
    if moving:
        notes.append("friction change columns (Coulomb, viscous) for joints " + ", ".join(str(j + 1) for j in moving))
    return FullPayload(theta, cov, tuple(g.joint for g in groups), res.residual_rms_nm,
                       {g.label: len(g.y) for g in groups}, res.condition_number, tuple(notes))
