"""Checks on the primary estimate itself, whichever solver made it, and on its agreement with the others.

Part of the quality gate (``payload_agent.evaluation.quality.evaluate``): the data-level checks
there use the general weighted fit whatever the primary; these look at the estimate the user gets.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from payload_agent.solvers import wls
from payload_agent.solvers.results import Estimate

SOLVER_AGREEMENT_Z = 4.0  # |m_primary − m_other| / √(σ_p² + σ_o²) above this fails (mass)
SOLVER_AGREEMENT_COG_D = 5.1  # Mahalanobis distance of the two centres of mass (χ²₃ tail 1e-5)


def make_check(name: str, value: float, limit: float, passed: bool, reason: str | None,
               **extra: Any) -> dict[str, Any]:
    """One row of the quality table: ``{"check", "value", "limit", "passed", "reason" (if failed), ...}``."""
    c = {"check": name, "value": float(value), "limit": float(limit), "passed": bool(passed), **extra}
    if not passed and reason:
        c["reason"] = reason
    return c


def solver_checks(primary: Estimate, others: Sequence[Estimate] = (), hint: str = "", *,
                  min_mass_z: float = 10.0, max_mass_kg: float = 50.0) -> list[dict[str, Any]]:
    """The checks on the primary estimate itself, whichever solver made it.

    - it reports an uncertainty (an estimate without one cannot be judged, nor written to a robot);
    - a primary other than the general fit (whose numbers the checks above use) gets its own mass
      significance and upper bound;
    - it agrees with every other solver's estimate on the same data that reports an uncertainty:
      |Δm| ≤ z·√(σ_primary² + σ_other²), and the centres of mass within a Mahalanobis distance
      under Σ_primary + Σ_other (their x and y are strongly correlated in the three-step). The
      two estimates share their data, so their errors are positively correlated and this σ is an
      upper bound of the difference's: the check is lenient on noise and catches bias (one-way
      friction, a model the data do not follow). ``hint`` ends the failure reasons (e.g. that
      uncalibrated drive gains are not in σ: the three-step mass depends on the ratio of the
      joint-2 and joint-3 gains, the general one far less).
    """
    out: list[dict[str, Any]] = []
    name = primary.solver
    std_m = primary.mass_std_kg
    has_std = (std_m is not None and math.isfinite(std_m) and std_m > 0 and primary.cog_std_m is not None
               and all(math.isfinite(v) for v in primary.cog_std_m))
    out.append(make_check(f"uncertainty reported ({name})", 1.0 if has_std else 0.0, 1.0, has_std,
                          f"the {name} estimate reports no uncertainty: it cannot be checked, and is not written "
                          "to a robot; use a solver that reports one (general, three-step)"))
    if not has_std:
        return out
    m = primary.mass_kg
    if name != "general":
        zm = m / std_m
        out.append(make_check(f"mass significance ({name})", zm, min_mass_z, zm >= min_mass_z,
                              f"{name}: identified mass {m:.4f} ± {std_m:.4f} kg is only {zm:.1f} σ above zero "
                              f"(at least {min_mass_z:g} σ needed): is the tool mounted, is the sweep long enough?",
                              mass_kg=m, mass_std_kg=std_m))
        out.append(make_check(f"mass upper bound ({name})", m, max_mass_kg, m <= max_mass_kg,
                              f"{name}: identified mass {m:.2f} kg exceeds {max_mass_kg:g} kg: check effort.unit and "
                              "effort.gains_nm_per_unit"))
    for other in others:
        so = other.mass_std_kg
        if other.solver == name or so is None or other.cog_std_m is None or not so > 0:
            continue
        pair = f"{name} vs {other.solver}"
        sigma = math.hypot(std_m, so)
        z = abs(m - other.mass_kg) / sigma
        out.append(make_check(f"mass {pair}", z, SOLVER_AGREEMENT_Z, z <= SOLVER_AGREEMENT_Z,
                              f"the {name} mass ({m:.4f} kg) and the {other.solver} mass ({other.mass_kg:.4f} kg) "
                              f"differ by {z:.1f} σ (limit {SOLVER_AGREEMENT_Z:g} σ): one of them is biased "
                              f"(friction not cancelled, a sweep the model does not fit){hint}",
                              difference_kg=m - other.mass_kg, sigma_kg=sigma, z=z, limit_z=SOLVER_AGREEMENT_Z))
        dc = 1000.0 * (np.asarray(primary.cog_m) - np.asarray(other.cog_m))
        cov = _cog_cov_mm(primary) + _cog_cov_mm(other)
        try:
            d = float(np.sqrt(max(dc @ np.linalg.solve(cov, dc), 0.0)))
        except np.linalg.LinAlgError:
            d = math.inf
        diffs = ", ".join(f"{a} {v:+.2f}" for a, v in zip("xyz", dc))
        out.append(make_check(f"cog {pair}", d, SOLVER_AGREEMENT_COG_D, d <= SOLVER_AGREEMENT_COG_D,
                              f"the centre of mass from {name} ({_mm(primary.cog_mm)}) and from {other.solver} "
                              f"({_mm(other.cog_mm)}) differ by {diffs} mm, {d:.1f} σ over x, y, z together "
                              f"(Mahalanobis; limit {SOLVER_AGREEMENT_COG_D:g}){hint}",
                              difference_mm=dc.tolist(), z=d, limit_z=SOLVER_AGREEMENT_COG_D))
    return out


def _cog_cov_mm(e: Estimate) -> np.ndarray:
    """3×3 covariance (mm²) of an estimate's centre of mass: from its θ covariance, else its stds."""
    if e.covariance is not None:
        theta = np.array([e.mass_kg, *(e.mass_kg * np.asarray(e.cog_m))])
        return 1e6 * wls.cog_with_covariance(theta, np.asarray(e.covariance, float)[:4, :4])[1]
    return np.diag([(1000.0 * v) ** 2 for v in e.cog_std_m or (0.0, 0.0, 0.0)])


def _mm(v: Sequence[float]) -> str:
    return ", ".join(f"{x:.2f}" for x in v) + " mm"
