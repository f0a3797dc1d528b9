"""Bidirectional sweeps: average the "up" and "down" legs at matching angles of the moving joint.

With the moving joint at the same angle q, the static model gives the same Δτ in both
directions, while every friction term odd in velocity (Coulomb, viscous, and the
load-dependent Coulomb part sign(q̇)·k·|τ|) flips sign. The average of the two legs at
the same angle cancels all of them, including what the empty-flange baseline could not
remove (load-dependent friction, friction drift between the runs).

The combined sweep has direction ``"both"``; the general and the three-step solver both
prefer it over the two legs (the three-step solver falls back to the published "up" leg
where only one direction was recorded).

The grid is uniform over the overlap, with no more points than the sparser leg has samples (the
averaged noise stays nearly independent). Where a leg's stream has a gap, several grid points
interpolate the same two samples of that leg and share their error; the combined sweep's noise map
(``DeltaSweep.noise_map``: the legs' maps interpolated at the grid) records that, and that of the
empty run's gaps each leg carries, so the fit counts every shared error once instead of the
samples being dropped.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from payload_agent.analysis.delta import DeltaSweep, interpolation_matrix
from payload_agent.errors import DataError
from payload_agent.types import SweepKey

COMBINED = "both"
MIN_OVERLAP_SAMPLES = 20


def _sorted_by_angle(d: DeltaSweep) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
    """(angles, q, Δτ, noise map) of a leg in the order of its moving joint's angle."""
    from scipy import sparse

    x = d.q[:, d.moving]
    order = np.argsort(x, kind="stable")
    noise = sparse.identity(len(x), format="csr") if d.noise_map is None else d.noise_map
    return x[order], d.q[order], d.dtau[order], sparse.csr_matrix(noise)[order]


def _noise_map(grid: np.ndarray, legs: list[tuple[np.ndarray, Any]]) -> Any:
    """``DeltaSweep.noise_map`` of the grid points: half of each leg's noise map interpolated at them (the
    legs' sources side by side; a leg without a map counts its own samples as the sources)."""
    from scipy import sparse

    return sparse.hstack([0.5 * (interpolation_matrix(grid, x) @ noise) for x, noise in legs], format="csr")


def _interp_columns(x_new: np.ndarray, x: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(x_new, x, values[:, c]) for c in range(values.shape[1])])


def combine_pair(up: DeltaSweep, down: DeltaSweep) -> DeltaSweep:
    """The friction-cancelling average of two legs of the same sweep, on a common angle grid."""
    if (up.key.pose, up.key.joint, up.key.speed_percent) != (down.key.pose, down.key.joint, down.key.speed_percent):
        raise DataError(f"cannot combine {up.key.name} with {down.key.name}: different sweeps")
    xu, qu, tu, su = _sorted_by_angle(up)
    xd, qd, td, sd = _sorted_by_angle(down)
    lo, hi = max(xu[0], xd[0]), min(xu[-1], xd[-1])
    eps = 1e-9 * max(hi - lo, 1e-12)  # samples at the overlap's ends count, whatever the rounding
    n = min(int(np.sum((xu >= lo - eps) & (xu <= hi + eps))), int(np.sum((xd >= lo - eps) & (xd <= hi + eps))))
    if n < MIN_OVERLAP_SAMPLES or not hi > lo:
        raise DataError(f"the up and down legs of {up.key.pose}-j{up.key.joint} share too few angles ({n} samples)")
    # no more grid points than the sparser leg has samples: the averaged noise stays nearly independent
    grid = np.linspace(lo, hi, n)
    q = 0.5 * (_interp_columns(grid, xu, qu) + _interp_columns(grid, xd, qd))
    q[:, up.moving] = grid
    dtau = 0.5 * (_interp_columns(grid, xu, tu) + _interp_columns(grid, xd, td))
    key = SweepKey(up.key.pose, up.key.joint, COMBINED, up.key.speed_percent)
    return DeltaSweep(key, q, dtau, 0.5 * (abs(up.speed_rad_s) + abs(down.speed_rad_s)),
                      _noise_map(grid, [(xu, su), (xd, sd)]) if up.noise_map is not None or down.noise_map is not None
                      else None)


def add_combined(deltas: dict[SweepKey, DeltaSweep]) -> tuple[dict[SweepKey, DeltaSweep], list[str]]:
    """``deltas`` plus one combined sweep per (pose, joint, speed) that has both legs; notes on failures."""
    out = dict(deltas)
    notes = []
    for key, up in deltas.items():
        if key.direction != "up":
            continue
        down = deltas.get(SweepKey(key.pose, key.joint, "down", key.speed_percent))
        if down is None:
            continue
        try:
            comb = combine_pair(up, down)
        except DataError as exc:
            notes.append(str(exc))
            continue
        out[comb.key] = comb
    return out, notes
