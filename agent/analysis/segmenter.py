"""Finds the constant-speed window of a sweep from the angle stream itself.

Static balance holds only where the moving joint does not accelerate: the
acceleration and deceleration phases of the PTP profile, and the standstill
before and after, are cut away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from payload_agent.errors import DataError

MIN_SAMPLES = 20


@dataclass(frozen=True)
class Window:
    start: int
    stop: int  # exclusive
    speed_rad_s: float  # signed cruise speed

    @property
    def slice(self) -> slice:
        return slice(self.start, self.stop)

    def __len__(self) -> int:
        return self.stop - self.start


def velocity(t: np.ndarray, angle: np.ndarray, half_width: int) -> np.ndarray:
    """Central-difference velocity over ±half_width samples (robust to jitter in sample times)."""
    n = len(angle)
    v = np.full(n, np.nan)
    k = half_width
    if n <= 2 * k:
        return v
    dt = t[2 * k:] - t[:-2 * k]
    with np.errstate(divide="ignore", invalid="ignore"):
        v[k:n - k] = np.where(dt > 0, (angle[2 * k:] - angle[:-2 * k]) / dt, np.nan)
    return v


def constant_speed_window(t: np.ndarray, angle: np.ndarray, *, tolerance: float = 0.02,
                          half_width: int = 3, trim: int = 3, where: str = "sweep") -> Window:
    """The longest run of samples whose speed is within ``tolerance`` (relative) of the cruise speed."""
    t = np.asarray(t, float)
    angle = np.asarray(angle, float)
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{where}: only {len(t)} samples recorded; cannot find a constant-speed window")
    v = velocity(t, angle, half_width)
    speed = np.abs(v)
    peak = np.nanmax(speed) if np.isfinite(speed).any() else 0.0
    if not peak > 0:
        raise DataError(f"{where}: the joint did not move")
    moving = speed >= 0.5 * peak
    cruise = float(np.nanmedian(v[moving]))
    ok = np.abs(v - cruise) <= tolerance * abs(cruise)
    ok &= np.isfinite(v)
    # longest contiguous run of ok samples
    best, start = (0, 0), None
    for i, flag in enumerate(np.append(ok, False)):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = None
    a, b = best[0] + trim, best[1] - trim
    if b - a < MIN_SAMPLES:
        raise DataError(f"{where}: only {max(b - a, 0)} samples at constant speed (need {MIN_SAMPLES}); "
                        f"sweep slower or over a longer range")
    return Window(a, b, cruise)
