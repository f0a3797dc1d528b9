"""Two recordings of the same motion, one with the tool and one without, put on one time base.

Recordings the agent did not make start whenever someone pressed record, at a jittery rate
(a UR logged through a PC: 2–30 ms between rows). Both are resampled onto an even grid at
their median period (the derivatives need one), and the loaded run is shifted in time until
its joint angles match the empty run's best (least squares over every joint, searched sample
by sample, then refined between samples). The empty run's effort is then read at the loaded
run's angles' times, so the two efforts are compared where the arm was in the same place.

The match is reported (rms and largest angle difference): a loaded arm tracks a velocity-
controlled trajectory a few mrad differently, which is fine; a different trajectory is not
(``MAX_RMS_RAD``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from payload_agent.errors import DataError
from payload_agent.recording.motion_csv import MotionRecording

MAX_RMS_RAD = 0.02  # about 1.1°: beyond this the two files do not record the same motion
MIN_OVERLAP = 0.5  # of the shorter recording


@dataclass(frozen=True)
class AlignedPair:
    """The loaded run on an even grid, with the empty run's effort at the same place on the path."""

    t: np.ndarray  # (n,) s, even grid, loaded run's clock from its first row
    q: np.ndarray  # (n, 6) rad, loaded run
    effort_loaded: np.ndarray  # (n, 6) in the recordings' effort unit
    effort_empty: np.ndarray  # (n, 6) the empty run at the matching times
    shift_s: float  # empty time = loaded time + shift_s (both from their first rows)
    rms_rad: float  # joint-angle mismatch after the shift
    max_rad: float
    period_s: float

    def to_json(self) -> dict:
        return {"shift_s": self.shift_s, "angle_rms_mrad": 1000 * self.rms_rad, "angle_max_mrad": 1000 * self.max_rad,
                "period_s": self.period_s, "samples": int(len(self.t))}


def resample(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(grid, t, x[:, c]) for c in range(x.shape[1])])


def _mismatch(qa: np.ndarray, qb: np.ndarray, shift: int, min_rows: int) -> float:
    """Mean squared angle difference of qa[i + shift] and qb[i] over their overlap (inf if too short)."""
    if shift >= 0:
        a, b = qa[shift:], qb
    else:
        a, b = qa, qb[-shift:]
    n = min(len(a), len(b))
    if n < min_rows:
        return float("inf")
    return float(np.mean((a[:n] - b[:n]) ** 2))


def align(empty: MotionRecording, loaded: MotionRecording) -> AlignedPair:
    """Put ``loaded`` on an even grid and read ``empty``'s effort where the arm was at the same angles."""
    h = float(np.round(min(empty.period_s, loaded.period_s), 4))
    if not h > 0:
        raise DataError("recorded motion: the recordings' time stamps do not advance")
    te, tl = empty.t - empty.t[0], loaded.t - loaded.t[0]
    ge, gl = np.arange(0.0, te[-1], h), np.arange(0.0, tl[-1], h)
    qe, ql = resample(te, empty.q, ge), resample(tl, loaded.q, gl)
    min_rows = int(MIN_OVERLAP * min(len(ge), len(gl)))
    if min_rows < 20:
        raise DataError("recorded motion: the recordings are too short to align")
    shifts = np.arange(-(len(gl) - min_rows), len(ge) - min_rows + 1)
    # coarse search on every 5th shift, then every shift around the best
    coarse = shifts[::5]
    costs = np.array([_mismatch(qe, ql, int(s), min_rows) for s in coarse])
    best = int(coarse[int(np.argmin(costs))])
    near = np.arange(best - 5, best + 6)
    costs = np.array([_mismatch(qe, ql, int(s), min_rows) for s in near])
    k = int(np.argmin(costs))
    best, c0 = int(near[k]), costs[k]
    frac = 0.0
    if 0 < k < len(near) - 1 and np.all(np.isfinite(costs[k - 1:k + 2])):
        cm, cp = costs[k - 1], costs[k + 1]
        denom = cm - 2 * c0 + cp
        frac = float(np.clip(0.5 * (cm - cp) / denom, -0.5, 0.5)) if denom > 0 else 0.0
    shift_s = (best + frac) * h
    inside = (gl + shift_s >= 0) & (gl + shift_s <= te[-1])
    t = gl[inside]
    q = ql[inside]
    q_empty = resample(te, empty.q, t + shift_s)
    diff = q - q_empty
    rms, mx = float(np.sqrt(np.mean(diff ** 2))), float(np.max(np.abs(diff)))
    if rms > MAX_RMS_RAD:
        raise DataError(f"recorded motion: {loaded.source} and {empty.source} do not record the same motion: after "
                        f"the best time shift ({shift_s:+.2f} s) the joint angles still differ by {np.degrees(rms):.2f}° "
                        f"rms ({np.degrees(mx):.1f}° at most; {np.degrees(MAX_RMS_RAD):.1f}° allowed)")
    return AlignedPair(t, q, resample(tl, loaded.effort, t), resample(te, empty.effort, t + shift_s),
                       shift_s, rms, mx, h)
