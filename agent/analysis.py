"""Everything after the recorder: segment, subtract the baseline, combine directions, solve, check.

``payload-agent solve RUN_DIR`` and ``run`` both come through here, so a recorded
run can always be re-analysed and gives the same answer.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from payload_agent.combine import add_combined
from payload_agent.delta import DeltaSweep, subtract_all
from payload_agent.errors import DataError
from payload_agent.kinematics import Kinematics
from payload_agent.planner import SweepKey
from payload_agent.results import Estimate
from payload_agent.rundata import load_manifest, load_phase
from payload_agent.solvers import SOLVERS, general

POSE_AGREEMENT_Z = 3.0  # |m_b − m_d| / σ above this fails the pose-agreement check


def deltas_for(run_dir: Path, gains: np.ndarray, baseline_dir: Path | None = None, *,
               combine: bool = True, notes: list[str] | None = None) -> dict[SweepKey, DeltaSweep]:
    """Loaded-minus-empty sweeps of a run; the empty phase comes from ``baseline_dir`` if given.

    With ``combine``, every sweep recorded in both directions also gets its friction-cancelling
    combined sweep (direction "both", see ``payload_agent.combine``); problems go to ``notes``.
    """
    manifest = load_manifest(run_dir)
    loaded = load_phase(run_dir, "loaded", gains, manifest)
    if not loaded:
        raise DataError(f"{run_dir}: no complete loaded sweep to analyse")
    empty_dir = Path(baseline_dir) if baseline_dir is not None else Path(run_dir)
    empty = load_phase(empty_dir, "empty", gains)
    deltas = subtract_all(loaded, empty)
    if combine:
        deltas, problems = add_combined(deltas)
        if notes is not None:
            notes.extend(problems)
    return deltas


def solve_all(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: str) -> tuple[Estimate, list[Estimate]]:
    """The primary solver's estimate, plus every other solver's that can be computed on the same data."""
    if primary not in SOLVERS:
        raise DataError(f"unknown solver {primary!r}; available: {', '.join(SOLVERS)}")
    main = SOLVERS[primary](deltas, kin)
    others = []
    for name, fn in SOLVERS.items():
        if name == primary:
            continue
        try:
            others.append(fn(deltas, kin))
        except DataError as exc:
            main.notes.append(f"{name} not computed: {exc}")
    return main, others


def quality_checks(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: Estimate) -> dict[str, Any]:
    """Redundant checks recorded beside the result (no gate yet: nothing here raises).

    - pose agreement: the general solver restricted to each pose's sweeps gives two independent
      masses; they must agree within their combined standard uncertainty (|z| <= 3);
    - the primary estimate's uncertainty, conditioning and worst residual.
    """
    q: dict[str, Any] = {"passed": True, "reasons": []}
    poses = sorted({k.pose for k in deltas})
    per_pose: dict[str, dict[str, float]] = {}
    for pose in poses:
        try:
            est = general.solve(deltas, kin, poses=[pose], name=f"general[{pose}]")
        except (DataError, np.linalg.LinAlgError) as exc:
            q["reasons"].append(f"pose {pose} alone: not solvable ({exc})")
            continue
        per_pose[pose] = {"mass_kg": est.mass_kg, "mass_std_kg": est.mass_std_kg,
                          "cog_mm": list(est.cog_mm), "cog_std_mm": [1000 * v for v in est.cog_std_m],
                          "condition_number": est.condition_number}
    q["per_pose"] = per_pose
    checks = []
    names = sorted(per_pose)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ea, eb = per_pose[a], per_pose[b]
            sigma = math.hypot(ea["mass_std_kg"], eb["mass_std_kg"])
            diff = ea["mass_kg"] - eb["mass_kg"]
            z = diff / sigma if sigma > 0 else (0.0 if diff == 0 else math.inf)
            ok = abs(z) <= POSE_AGREEMENT_Z
            checks.append({"check": f"mass pose {a} vs pose {b}", "difference_kg": diff, "sigma_kg": sigma,
                           "z": z, "limit_z": POSE_AGREEMENT_Z, "passed": ok})
            if not ok:
                q["reasons"].append(f"mass from pose {a} ({ea['mass_kg']:.4f} kg) and from pose {b} "
                                    f"({eb['mass_kg']:.4f} kg) differ by {abs(z):.1f} σ "
                                    f"(limit {POSE_AGREEMENT_Z:g} σ): friction or gain error not cancelled?")
    if len(per_pose) < 2:
        q["reasons"].append("fewer than two poses solvable on their own: no pose-agreement check")
    q["checks"] = checks
    q["primary"] = {"solver": primary.solver, "condition_number": primary.condition_number,
                    "mass_std_kg": primary.mass_std_kg,
                    "cog_std_mm": None if primary.cog_std_m is None else [1000 * v for v in primary.cog_std_m],
                    "max_residual_rms_nm": max(primary.residual_rms_nm.values(), default=None)}
    if primary.condition_number is not None and primary.condition_number > 1e6:
        q["reasons"].append(f"ill-conditioned ({primary.condition_number:.3g})")
        checks.append({"check": "condition number", "value": primary.condition_number, "limit": 1e6,
                       "passed": False})
    q["passed"] = all(c["passed"] for c in checks) and len(per_pose) >= 2
    return q
