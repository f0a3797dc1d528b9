"""A physically possible inertia tensor closest to an estimate, in the estimate's own covariance metric.

A rigid body's inertia about its centre of mass is I = tr(Σ)·1 − Σ, where Σ = ∫ r rᵀ dm is its
(positive semi-definite) second-moment matrix; every such I is positive semi-definite and its
principal moments obey the triangle inequalities, and every I that obeys them has such a Σ
(Wensing, Kim and Slotine, arXiv:1701.04395: the constraints on the covariance of the mass
distribution; Traversaro et al., arXiv:1610.08703: "full physical consistency"; docs/sources.md). So the consistent
set is parameterised by Σ = L·Lᵀ (L lower triangular, six numbers), and the projection minimises
the Mahalanobis distance (x(L) − x̂)ᵀ C⁻¹ (x(L) − x̂) over L, x the six distinct elements.
An estimate that is already consistent is returned unchanged.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

ELEMENTS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # xx, xy, xz, yy, yz, zz


def to_vector(inertia: np.ndarray) -> np.ndarray:
    return np.array([inertia[i, j] for i, j in ELEMENTS])


def to_tensor(x: np.ndarray) -> np.ndarray:
    out = np.zeros((3, 3))
    for v, (i, j) in zip(x, ELEMENTS):
        out[i, j] = out[j, i] = v
    return out


def consistency_problem(inertia: np.ndarray, rel_tol: float = 1e-9) -> str | None:
    """Why an inertia tensor about the centre of mass is not physically possible, or None."""
    moments = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    scale = max(float(np.max(np.abs(moments))), 1e-300)
    if moments[0] <= rel_tol * scale:
        return f"not positive definite (principal moments {', '.join(f'{v:.3g}' for v in moments)} kg·m²)"
    if moments[2] > (moments[0] + moments[1]) * (1 + rel_tol):
        return (f"a principal moment ({moments[2]:.3g} kg·m²) exceeds the sum of the other two "
                f"({moments[0]:.3g} + {moments[1]:.3g}; triangle inequality)")
    return None


def _from_cholesky(p: np.ndarray) -> np.ndarray:
    L = np.zeros((3, 3))
    L[np.tril_indices(3)] = p
    S = L @ L.T
    return np.trace(S) * np.eye(3) - S


def project_consistent(inertia: np.ndarray, cov6: np.ndarray) -> tuple[np.ndarray, str | None]:
    """(consistent tensor, why the estimate was not consistent or None). ``cov6``: covariance of ``to_vector``."""
    inertia = 0.5 * (inertia + inertia.T)
    problem = consistency_problem(inertia)
    if problem is None:
        return inertia, None
    x_hat = to_vector(inertia)
    scale = max(float(np.max(np.abs(np.linalg.eigvalsh(inertia)))), 1e-9)
    C = np.asarray(cov6, float) + np.eye(6) * (1e-6 * scale) ** 2
    white = np.linalg.cholesky(np.linalg.inv(C)).T  # r = white·(x − x̂): |r|² is the Mahalanobis distance
    # start from the second-moment matrix of the estimate, clipped to positive definite
    S = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    w, V = np.linalg.eigh(S)
    S0 = (V * np.maximum(w, 1e-3 * scale)) @ V.T
    p0 = np.linalg.cholesky(S0)[np.tril_indices(3)]
    sol = least_squares(lambda p: white @ (to_vector(_from_cholesky(p)) - x_hat), p0, x_scale=np.sqrt(scale),
                        xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return _from_cholesky(sol.x), problem
