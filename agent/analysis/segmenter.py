"""The constant-speed window of a sweep: taken from the commanded profile, verified on the data.

Static balance holds only where the moving joint does not accelerate. The plan says where
that is: a sweep is one synchronised trapezoidal PTP move (``payload_agent.model.profile``)
from the previous move's target to its own, at a known speed and acceleration, so the
angle interval where the joint cruises follows from the profile math alone
(``SweepCommand.cruise_interval``: the ramps, plus a margin for a controller whose ramps
are a little longer). The empty and the loaded run of a sweep share their command, so they
use the same angle interval by construction, whatever the noise.

The data then verify that interval (``cruise_window``): the joint's velocity, from straight-
line fits of angle on time over a window whose length scales with the sample rate, the speed
and the noise measured in the same data (so 1e-5 rad of angle noise at 1 % speed and
timestamp jitter at 25 % give the same relative precision), must stay within
max(``REL_TOL``, ``Z_LIMIT`` standard errors) of the cruise speed. Samples that fail at the
ends of the interval (a controller ramping longer than planned) are cut off, with a guard of
half a fit window next to them; if less than ``MIN_VERIFIED_FRACTION`` of the interval is
left, the sweep is refused with the numbers.

Without a command (data recorded by other tools, plans not on file) the window is found in
the data alone: the longest run of samples at the cruise speed, with the same noise-aware
velocity, less a guard of half a fit window at each end.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from payload_agent.errors import DataError
from payload_agent.model.profile import JointPath
from payload_agent.types import SweepKey

MIN_SAMPLES = 20
REL_TOL = 0.02  # a window's velocity may differ this much (relative) from the cruise speed ...
Z_LIMIT = 5.0  # ... or this many of its standard errors, whichever is larger
TARGET_REL_SE = 0.005  # fit windows long enough for a velocity standard error of 0.5 % of the speed
MIN_FIT_SAMPLES = 5
PROBE_FIT_SAMPLES = 9  # first pass, to measure the noise
MARGIN_RAMP_FRACTION = 0.25  # margin beyond the planned ramps: this fraction of the ramp's travel ...
MARGIN_MIN_RAD = math.radians(0.2)  # ... plus this much
MIN_VERIFIED_FRACTION = 0.5  # of the planned interval's travel that must pass the data check
START_TOLERANCE_RAD = math.radians(1.0)  # recorded start vs the plan's start of the sweep
DATA_WINDOW_CACHE = 256  # windows found without a command, kept by content (a few MB at most)


@dataclass(frozen=True)
class SweepCommand:
    """The PTP move of one sweep as the plan commanded it (all six joints, rad, rad/s, rad/s²)."""

    joint: int  # 0-based moving joint
    start_rad: tuple[float, ...]  # the previous move's target
    target_rad: tuple[float, ...]
    speed_rad_s: float  # leading-joint speed
    accel_rad_s2: float

    @property
    def direction(self) -> float:
        """+1 if the moving joint's angle increases along the move, −1 otherwise."""
        return 1.0 if self.target_rad[self.joint] >= self.start_rad[self.joint] else -1.0

    def cruise_interval(self, margin_fraction: float = MARGIN_RAMP_FRACTION,
                        margin_min_rad: float = MARGIN_MIN_RAD) -> tuple[float, float]:
        """(low, high) angle of the moving joint where the profile cruises, less the margin.

        The synchronised trapezoid (``model.profile.JointPath``) gives the leading joint's path
        coordinate s; the ramps end at s = d_acc and start again at L − d_acc; the moving joint
        is at start + direction·s. Raises DataError if nothing is left.
        """
        path = JointPath(np.asarray(self.start_rad, float), np.asarray(self.target_rad, float), 0.0,
                         self.speed_rad_s, self.accel_rad_s2, np.full(len(self.start_rad), np.inf),
                         np.full(len(self.start_rad), np.inf))
        flat = [ph for ph in path.phases if ph.a == 0.0 and ph.duration > 0.0]
        travel = math.degrees(abs(self.target_rad[self.joint] - self.start_rad[self.joint]))
        speed, accel = math.degrees(self.speed_rad_s), math.degrees(self.accel_rad_s2)
        if not flat:
            raise DataError(f"joint {self.joint + 1} never reaches constant speed over its {travel:.1f}° sweep at "
                            f"{speed:.2f}°/s and {accel:.1f}°/s²: "
                            "lower the speed, raise the acceleration or widen the sweep range")
        d_acc = flat[0].s0
        margin = margin_fraction * d_acc + margin_min_rad / max(abs(path.direction[self.joint]), 1e-12)
        s_lo, s_hi = d_acc + margin, path.length - d_acc - margin
        if not s_hi > s_lo:
            raise DataError(f"joint {self.joint + 1}: its {travel:.1f}° sweep at {speed:.2f}°/s "
                            f"cruises over only {math.degrees(path.length - 2 * d_acc):.2f}°, less than the "
                            f"{math.degrees(2 * margin):.2f}° the segmentation keeps off the ramps; "
                            "lower the speed or widen the sweep range")
        a = self.start_rad[self.joint] + path.direction[self.joint] * s_lo
        b = self.start_rad[self.joint] + path.direction[self.joint] * s_hi
        return (min(a, b), max(a, b))

    @classmethod
    def from_plan_entries(cls, previous: Mapping[str, Any], entry: Mapping[str, Any], joint: int) -> "SweepCommand":
        """From two consecutive manifest ``plan`` entries (degrees), the second being the sweep."""
        return cls(joint, tuple(math.radians(v) for v in previous["target_deg"]),
                   tuple(math.radians(v) for v in entry["target_deg"]),
                   math.radians(float(entry["speed_deg_s"])), math.radians(float(entry["accel_deg_s2"])))


@dataclass(frozen=True)
class Window:
    """The verified constant-speed samples of one sweep."""

    start: int
    stop: int  # exclusive
    speed_rad_s: float  # signed cruise speed measured over the window
    low_rad: float = math.nan  # angle interval the window covers (moving joint)
    high_rad: float = math.nan
    planned: tuple[float, float] | None = None  # the command's cruise interval, when there was a command
    fit_samples: int = 0  # samples per velocity fit
    speed_std_rad_s: float = math.nan  # standard error of one fit window's velocity

    @property
    def slice(self) -> slice:
        return slice(self.start, self.stop)

    def __len__(self) -> int:
        return self.stop - self.start


def velocity(t: np.ndarray, angle: np.ndarray, half_width: int) -> np.ndarray:
    """Central-difference velocity over ±half_width samples (NaN where the window does not fit)."""
    n = len(angle)
    v = np.full(n, np.nan)
    k = half_width
    if n <= 2 * k:
        return v
    dt = t[2 * k:] - t[:-2 * k]
    with np.errstate(divide="ignore", invalid="ignore"):
        v[k:n - k] = np.where(dt > 0, (angle[2 * k:] - angle[:-2 * k]) / dt, np.nan)
    return v


def _window_fits(t: np.ndarray, x: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slope, residual std and Σ(t − t̄)² of a straight-line fit over every run of ``w`` samples."""
    T = sliding_window_view(t - t[0], w)
    X = sliding_window_view(x - x[0], w)
    tc = T - T.mean(axis=1, keepdims=True)
    xc = X - X.mean(axis=1, keepdims=True)
    stt = np.einsum("ij,ij->i", tc, tc)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(stt > 0, np.einsum("ij,ij->i", tc, xc) / stt, np.nan)
    res = xc - slope[:, None] * tc
    s = np.sqrt(np.einsum("ij,ij->i", res, res) / max(w - 2, 1))
    return slope, s, stt


def fit_window_samples(t: np.ndarray, angle: np.ndarray, speed_rad_s: float) -> tuple[int, float]:
    """Samples per velocity fit, and the angle noise σ (rad, jitter included) it was sized for.

    σ comes from straight-line fits over short windows of the data (their residual std,
    median over the sweep: angle noise plus speed × timestamp jitter). A fit over n samples
    spanning T = n/f has a slope standard error σ·√(12/(n·T²)); n is chosen so that this is
    ``TARGET_REL_SE`` of the speed, at least ``MIN_FIT_SAMPLES`` and at most a third of the data.
    """
    n = len(t)
    w0 = min(PROBE_FIT_SAMPLES, n)
    if w0 < 3:
        return max(n, 1), math.nan
    _, s, _ = _window_fits(t, angle, w0)
    sigma = float(np.nanmedian(s))
    span = float(t[-1] - t[0])
    rate = (n - 1) / span if span > 0 else math.nan
    target = TARGET_REL_SE * abs(speed_rad_s)
    if not (math.isfinite(rate) and target > 0 and math.isfinite(sigma)):
        return MIN_FIT_SAMPLES, sigma
    duration = (12.0 * sigma ** 2 / (rate * target ** 2)) ** (1.0 / 3.0)
    w = int(math.ceil(duration * rate)) + 1
    return int(min(max(w, MIN_FIT_SAMPLES), max(MIN_FIT_SAMPLES, n // 3))), sigma


def local_velocity(t: np.ndarray, angle: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Per sample: velocity from the ``w``-sample line fit centred on it, and its standard error.

    The standard error uses the median residual σ of all fits (one noise level per sweep); samples
    within half a window of either end get the nearest full window's values.
    """
    n = len(t)
    w = min(w, n)
    slope, s, stt = _window_fits(t, angle, w)
    sigma = float(np.nanmedian(s)) if len(s) else math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        se = sigma / np.sqrt(stt)
    v = np.empty(n)
    e = np.empty(n)
    h = w // 2
    v[h:h + len(slope)] = slope
    e[h:h + len(se)] = se
    v[:h], e[:h] = slope[0], se[0]
    v[h + len(slope):], e[h + len(se):] = slope[-1], se[-1]
    return v, e


def _longest_run(ok: np.ndarray) -> tuple[int, int]:
    best, start = (0, 0), None
    for i, flag in enumerate(np.append(ok, False)):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = None
    return best


def cruise_window(t: np.ndarray, angle: np.ndarray, command: SweepCommand | None = None, *,
                  where: str = "sweep") -> Window:
    """The constant-speed samples of one sweep: the command's cruise interval, verified on the data.

    ``angle`` is the moving joint's. Without ``command`` the window is found from the data alone
    (see the module docstring). Raises DataError naming ``where`` when the data do not confirm a
    constant-speed window of at least ``MIN_SAMPLES`` samples.
    """
    t = np.asarray(t, float)
    angle = np.asarray(angle, float)
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{where}: only {len(t)} samples recorded; cannot find a constant-speed window")
    if command is None:
        return _window_from_bytes(t.tobytes(), angle.tobytes(), where)
    lo, hi = command.cruise_interval()
    start = command.start_rad[command.joint]
    if abs(angle[0] - start) > START_TOLERANCE_RAD:
        raise DataError(f"{where}: the sweep started at {math.degrees(angle[0]):.2f}°, the plan says "
                        f"{math.degrees(start):.2f}° (joint {command.joint + 1}); was it recorded with this plan?")
    inside = np.flatnonzero((angle >= lo) & (angle <= hi))
    if len(inside) < MIN_SAMPLES:
        raise DataError(f"{where}: only {len(inside)} samples inside the planned constant-speed interval "
                        f"{math.degrees(lo):.2f}°–{math.degrees(hi):.2f}° (need {MIN_SAMPLES}); "
                        "sweep slower or over a longer range, or check the sample rate")
    a, b = int(inside[0]), int(inside[-1]) + 1
    ts, xs = t[a:b], angle[a:b]
    w, _ = fit_window_samples(ts, xs, command.speed_rad_s)
    v, se = local_velocity(ts, xs, w)
    cruise = float(np.nanmedian(v))
    if not cruise * command.direction > 0:
        raise DataError(f"{where}: joint {command.joint + 1} did not move in the commanded direction "
                        f"inside its planned constant-speed interval (median speed {math.degrees(cruise):.3f}°/s)")
    limit = np.maximum(REL_TOL * abs(cruise), Z_LIMIT * se)
    dev = np.abs(v - cruise)
    ok = dev <= limit
    r0, r1 = _longest_run(ok)
    guard = w // 2 + 1  # next to a failed fit the speed is still changing, if less than the limit
    r0 = r0 + guard if r0 > 0 else r0
    r1 = r1 - guard if r1 < len(ok) else r1
    covered = abs(xs[r1 - 1] - xs[r0]) if r1 > r0 else 0.0
    if r1 - r0 < MIN_SAMPLES or covered < MIN_VERIFIED_FRACTION * (hi - lo):
        if ok.all():  # every sample turns at the cruise speed: what is missing is samples
            raise DataError(_hole_message(where, command.joint, angle, lo, hi, covered))
        worst = int(np.argmax(dev / limit))
        raise DataError(
            f"{where}: joint {command.joint + 1} does not turn at constant speed over the planned interval "
            f"{math.degrees(lo):.2f}°–{math.degrees(hi):.2f}°: its speed is {math.degrees(v[worst]):.3f}°/s at "
            f"{math.degrees(xs[worst]):.2f}° against {math.degrees(cruise):.3f}°/s "
            f"(limit ±{math.degrees(limit[worst]):.3f}°/s); "
            f"only {math.degrees(covered):.2f}° of {math.degrees(hi - lo):.2f}° pass. Does the controller run the "
            "commanded speed and acceleration (speed override at 100 %)?")
    seg = xs[r0:r1]
    return Window(a + r0, a + r1, cruise, float(seg.min()), float(seg.max()), (lo, hi), w,
                  float(np.nanmedian(se)))


def _hole_message(where: str, joint: int, angle: np.ndarray, lo: float, hi: float, covered: float) -> str:
    """A sweep whose samples all turn at the cruise speed but cover too little of the planned interval: the
    stream left a hole there (a stall of the sample stream shorter than the watchdog's limit)."""
    edges = np.concatenate(([lo], np.sort(angle[(angle > lo) & (angle < hi)]), [hi]))
    i = int(np.argmax(np.diff(edges)))
    a, b = sorted((edges[i], edges[i + 1]), key=lambda v: abs(v - angle[0]))  # in the sweep's direction
    return (f"{where}: joint {joint + 1} has no samples from {math.degrees(a):.2f}° to {math.degrees(b):.2f}° of "
            f"the planned constant-speed interval {math.degrees(lo):.2f}°–{math.degrees(hi):.2f}°: only "
            f"{math.degrees(covered):.2f}° of it are recorded (need {100 * MIN_VERIFIED_FRACTION:.0f} %). The sample "
            "stream stalled for less than the watchdog's limit (safety.max_stream_gap_ms); redo the sweep "
            "(--retry-sweeps)")


@functools.lru_cache(maxsize=DATA_WINDOW_CACHE)
def _window_from_bytes(t: bytes, angle: bytes, where: str) -> Window:
    """``_window_from_data`` keyed by the samples' content: the window depends on the times and the moving joint's
    angles only, and a run's sweeps are cut again for every subtraction (each analysis's terms and fits, a plan's
    candidates, a loop over noise draws added to the same efforts). The same bytes give the same window, bit for bit."""
    return _window_from_data(np.frombuffer(t), np.frombuffer(angle), where)


def _window_from_data(t: np.ndarray, angle: np.ndarray, where: str) -> Window:
    """No command: the longest run at the cruise speed, found with the same noise-aware velocity."""
    w_probe = min(PROBE_FIT_SAMPLES, len(t))
    v0, _ = local_velocity(t, angle, w_probe)
    speed = np.abs(v0)
    peak = float(np.nanmax(speed)) if np.isfinite(speed).any() else 0.0
    if not peak > 0:
        raise DataError(f"{where}: the joint did not move")
    guess = float(np.nanmedian(v0[speed >= 0.5 * peak]))
    w, _ = fit_window_samples(t, angle, guess)
    v, se = local_velocity(t, angle, w)
    moving = np.abs(v) >= 0.5 * np.nanmax(np.abs(v))
    cruise = float(np.nanmedian(v[moving]))
    ok = np.abs(v - cruise) <= np.maximum(REL_TOL * abs(cruise), Z_LIMIT * se)
    r0, r1 = _longest_run(ok)
    guard = w // 2 + 1  # a fit window reaching into a ramp still passes while mostly on the flat part
    a, b = r0 + guard, r1 - guard
    if b - a < MIN_SAMPLES:
        raise DataError(f"{where}: only {max(b - a, 0)} samples at constant speed (need {MIN_SAMPLES}); "
                        f"sweep slower or over a longer range")
    seg = angle[a:b]
    return Window(a, b, cruise, float(seg.min()), float(seg.max()), None, w, float(np.median(se[a:b])))


def sweep_commands(moves: Sequence[Any]) -> dict[SweepKey, SweepCommand]:
    """SweepKey -> SweepCommand for every sweep of a plan: ``Plan.moves`` or a manifest's ``plan`` list.

    The start of each sweep is the previous move's target.
    """
    entries = [m.to_json() if hasattr(m, "to_json") else m for m in moves]
    out = {}
    for prev, entry in zip(entries, entries[1:]):
        sw = entry.get("sweep") if entry.get("kind", "sweep") == "sweep" else None
        if not sw:
            continue
        key = SweepKey(sw["pose"], int(sw["joint"]), sw["direction"], float(sw["speed_percent"]))
        out[key] = SweepCommand.from_plan_entries(prev, entry, int(sw["joint"]) - 1)
    return out
