"""Baseline subtraction: loaded minus empty effort at the same joint angles.

Sweeps are matched by pose, joint, direction and speed. Both runs of a sweep are segmented
with the same command (the plan's PTP move), so their constant-speed windows are the same
angle interval by construction; the data check may trim either at its ends
(``segmenter.cruise_window``), and the subtraction keeps the angles both verified. The empty
run's effort is interpolated at the loaded run's angles of the moving joint. What remains is
the payload's gravity torque (plus whatever friction did not cancel).

A stream with gaps (a busy host's simulated controller, a congested network) leaves intervals of
the empty run far wider than its sample spacing; every loaded sample inside one gets the empty
effort from the same two samples, so their deltas carry one shared interpolation error. The
subtraction keeps those samples (the quality gate counts them) and records instead how each delta
sample's noise is made of the runs' independent sample noises (``DeltaSweep.noise_map``): the fit
takes the covariance of its scores from that map (``solvers.wls.fit``), so neither θ's σ nor the
wrist offsets' χ² treats such a run as many independent observations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from payload_agent.analysis.segmenter import SweepCommand, Window, cruise_window
from payload_agent.errors import DataError
from payload_agent.recording.rundata import SweepData
from payload_agent.types import SweepKey

MIN_OVERLAP_SAMPLES = 20


@dataclass
class DeltaSweep:
    key: SweepKey
    q: np.ndarray  # (n, 6) loaded-run angles, rad
    dtau: np.ndarray  # (n, 6) loaded - empty effort, N·m
    speed_rad_s: float
    # (n, s) sparse: each sample's noise as a combination of s independent sample noises of the runs
    # (loaded and empty, of each leg); None: unknown (the samples' noises taken as independent)
    noise_map: Any = None

    @property
    def moving(self) -> int:
        return self.key.joint - 1


def window_of(sweep: SweepData, command: SweepCommand | None = None) -> Window:
    """The sweep's verified constant-speed window (from ``command`` if given, else from the data alone)."""
    j = sweep.key.joint - 1
    return cruise_window(sweep.t, sweep.q[:, j], command, where=sweep.source)


def interval_of(x: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The index i of the interval [xs[i], xs[i + 1]] of the sorted ``xs`` that ``np.interp`` uses at each ``x``."""
    return np.clip(np.searchsorted(xs, x), 1, len(xs) - 1) - 1


def subtract(loaded: SweepData, empty: SweepData, command: SweepCommand | None = None) -> DeltaSweep:
    if loaded.key != empty.key:
        raise DataError(f"cannot subtract {empty.key} from {loaded.key}: different sweeps")
    j = loaded.key.joint - 1
    wl, we = window_of(loaded, command), window_of(empty, command)
    lo, hi = max(wl.low_rad, we.low_rad), min(wl.high_rad, we.high_rad)
    xe = empty.q[we.slice, j]
    ye = empty.effort_nm[we.slice]
    order = np.argsort(xe)
    xe, ye = xe[order], ye[order]
    q = loaded.q[wl.slice]
    x = q[:, j]
    inside = (x >= max(xe[0], lo)) & (x <= min(xe[-1], hi))
    if inside.sum() < MIN_OVERLAP_SAMPLES:
        raise DataError(f"{loaded.source}: the loaded and empty sweeps hardly overlap in joint {j + 1} angle "
                        f"({inside.sum()} samples); was the baseline recorded with the same procedure?")
    q = q[inside]
    x = x[inside]
    empty_at = np.column_stack([np.interp(x, xe, ye[:, c]) for c in range(ye.shape[1])])
    return DeltaSweep(loaded.key, q, loaded.effort_nm[wl.slice][inside] - empty_at, wl.speed_rad_s,
                      _noise_map(x, xe))


def interpolation_matrix(x: np.ndarray, xs: np.ndarray) -> Any:
    """(len(x), len(xs)) sparse P with P·v = np.interp(x, xs, v) for the sorted ``xs``."""
    from scipy import sparse

    iv = interval_of(x, xs)
    span = np.maximum(xs[iv + 1] - xs[iv], 1e-300)
    a = np.clip((x - xs[iv]) / span, 0.0, 1.0)
    rows = np.arange(len(x))
    return sparse.csr_matrix((np.r_[1.0 - a, a], (np.r_[rows, rows], np.r_[iv, iv + 1])), shape=(len(x), len(xs)))


def _noise_map(x: np.ndarray, xe: np.ndarray) -> Any:
    """``DeltaSweep.noise_map`` of loaded samples at angles ``x`` minus the empty run interpolated at them
    (sources: these loaded samples, then the empty samples at the sorted ``xe``)."""
    from scipy import sparse

    return sparse.hstack([sparse.identity(len(x), format="csr"), -interpolation_matrix(x, xe)], format="csr")


def subtract_all(loaded: dict[SweepKey, SweepData], empty: dict[SweepKey, SweepData],
                 commands: Mapping[SweepKey, SweepCommand] | None = None) -> dict[SweepKey, DeltaSweep]:
    """Every loaded sweep minus its empty one; ``commands`` (``segmenter.sweep_commands`` of the plan)
    place the constant-speed windows, else they are found in the data alone."""
    missing = [k.name for k in loaded if k not in empty]
    if missing:
        raise DataError(f"the empty-flange baseline has no sweep matching {', '.join(missing)} "
                        f"(same pose, joint, direction and speed)")
    commands = commands or {}
    return {k: subtract(v, empty[k], commands.get(k)) for k, v in loaded.items()}
