"""Per-joint motor-current noise of a real arm, measured in recordings of moving joints.

    python -m benchmarks.effort_noise DIR [--columns MAP] [--half-window N] [--min-speed RAD_S]

DIR is laid out like ``shared/realdata/ur10e-mamedov/`` (``pairs.csv`` naming the recordings);
every recording it names is read with the agent's own reader (``recording.motion_csv``, which
drops and reports the rubbish rows at a log's start). Not a test: the data is not in the project.
It grounds the simulated arms' ``simulation.noise_nm`` (docs/sources.md, "Effort noise").

Method (why: the excitation has no rest, so the noise has to be separated from a moving signal):

1. **Local fit** (the number used): around every sample, a quadratic in time through its
   ``2N+1`` neighbours (about ±N·10 ms; the rows are unevenly spaced, so the fit uses the real
   timestamps). The residual at the centre, divided by ``sqrt(1 − h)`` (h: the fit's own weight
   on that sample), has the noise's standard deviation if the signal is smooth over the window.
   Samples whose window holds a speed below ``--min-speed`` (a reversal: Coulomb friction jumps)
   or a gap over 40 ms are left out; σ is the robust 1.4826·MAD, so what little of the motion
   the quadratic misses does not inflate it (the plain standard deviation is printed beside it).
2. **Actual − target**: the same on ``actual_current − target_current`` (the controller's
   feed-forward and feedback taken out first): close to (1) when (1) measures noise, not motion.
3. **Whiteness**: half the mean square difference of raw rows k apart (k = 1, 2, 3: about 10, 20,
   30 ms; the logs are at ~100 Hz, gaps of 8–12 ms), over σ² of (1), without fitting anything.
   About 1 at every k means the noise is independent from row to row, i.e. white up to the logs'
   50 Hz; whether it is white up to a UR's 500 Hz these logs cannot show (docs/sources.md).

Also printed: the same σ at rest (rows with every joint slower than 1 mrad/s, where a log has
them) and in fast motion (> 0.8 rad/s), because the noise during motion is what the fits see.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.realdata import MAMEDOV_COLUMNS, read_pairs
from payload_agent.recording.motion_csv import read_motion_csv

MAX_GAP_S = 0.040
LAGS_ROWS = (1, 2, 3)
REST_RAD_S = 1e-3
FAST_RAD_S = 0.8


@dataclass(frozen=True)
class JointNoise:
    """One recording's current noise per joint (A) and the checks beside it."""

    source: str
    rows: int
    dropped: int
    used: np.ndarray  # (6,) samples that entered the local-fit σ
    local_fit_a: np.ndarray  # (6,) robust σ of the local-fit residual
    local_fit_std_a: np.ndarray  # (6,) plain standard deviation of the same
    actual_minus_target_a: np.ndarray  # (6,) robust σ of (actual − target) around its local fit
    whiteness: np.ndarray  # (lags, 6) half mean square raw difference / σ², rows k apart
    median_gap_ms: float
    at_rest_a: np.ndarray  # (6,) robust σ where the whole arm stands (NaN: no such rows)
    fast_a: np.ndarray  # (6,) robust σ where the joint moves faster than FAST_RAD_S
    rms_current_a: np.ndarray  # (6,) the signal's own size


def local_quadratic_residuals(t: np.ndarray, y: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Residual at each centre of a quadratic fit through its ±half neighbours, scaled by 1/sqrt(1 − h).

    Returns (residuals (n, k) with NaN at the ends, and the window's largest time gap (n,))."""
    n = len(t)
    out = np.full(y.shape, np.nan)
    widest = np.full(n, np.inf)
    for c in range(half, n - half):
        sl = slice(c - half, c + half + 1)
        dt = t[sl] - t[c]
        design = np.stack([np.ones_like(dt), dt, dt * dt], axis=1)
        pinv = np.linalg.pinv(design)
        hat_row = design[half] @ pinv  # the fitted value at the centre as weights on the window
        out[c] = (y[c] - hat_row @ y[sl]) / np.sqrt(1.0 - hat_row[half])
        widest[c] = np.max(np.diff(t[sl]))
    return out, widest


def robust_std(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else float("nan")


def measure(path: Path, columns: str | None, half: int, min_speed: float) -> JointNoise:
    rec = read_motion_csv(path, columns)
    if rec.current_a is None:
        raise SystemExit(f"{path}: no actual_current columns")
    t, cur = rec.t, rec.current_a
    qd = rec.qd if rec.qd is not None else np.gradient(rec.q, t, axis=0)
    res, widest = local_quadratic_residuals(t, cur, half)
    slow = np.abs(qd) < min_speed
    # a window holding a slow sample (a reversal) is left out: sliding maximum of the flag
    near_slow = np.zeros_like(slow)
    for k in range(-half, half + 1):
        near_slow |= np.roll(slow, k, axis=0)
    ok = np.isfinite(res) & ~near_slow & (widest <= MAX_GAP_S)[:, None]
    local = np.array([robust_std(res[ok[:, j], j]) for j in range(6)])
    plain = np.array([float(np.std(res[ok[:, j], j])) for j in range(6)])
    if rec.target_current_a is not None:
        res_d, _ = local_quadratic_residuals(t, cur - rec.target_current_a, half)
        diff = np.array([robust_std(res_d[ok[:, j], j]) for j in range(6)])
    else:
        diff = np.full(6, np.nan)
    white = np.full((len(LAGS_ROWS), 6), np.nan)
    for b, k in enumerate(LAGS_ROWS):
        step = cur[k:] - cur[:-k]
        for j in range(6):
            sel = ~(near_slow[k:, j] | near_slow[:-k, j]) & (t[k:] - t[:-k] <= k * MAX_GAP_S / 2)
            white[b, j] = 0.5 * np.mean(step[sel, j] ** 2) / local[j] ** 2
    finite = np.isfinite(res)
    rest = np.all(np.abs(qd) < REST_RAD_S, axis=1)
    at_rest = np.array([robust_std(res[finite[:, j] & rest, j]) if (finite[:, j] & rest).sum() >= 50 else np.nan
                        for j in range(6)])
    fast = np.array([robust_std(res[ok[:, j] & (np.abs(qd[:, j]) > FAST_RAD_S), j]) for j in range(6)])
    return JointNoise(str(path.name), rec.rows, len(rec.dropped), ok.sum(axis=0), local, plain, diff, white,
                      1000 * float(np.median(np.diff(t))), at_rest, fast, np.sqrt(np.mean(cur ** 2, axis=0)))


def fmt(values, spec: str = ".4f") -> str:
    return " ".join(f"{v:{spec}}" for v in values)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a folder with pairs.csv and the recordings it names")
    p.add_argument("--columns", default=MAMEDOV_COLUMNS, help="column map (default: the ur10e-mamedov layout)")
    p.add_argument("--half-window", type=int, default=5, help="neighbours each side in the local fit (default 5)")
    p.add_argument("--min-speed", type=float, default=0.05,
                   help="rad/s; windows with a slower sample (reversals) are left out (default 0.05)")
    args = p.parse_args(argv)
    names = []
    for pair in read_pairs(args.folder):
        names += [pair["empty"], pair["loaded"]]
    results = [measure(args.folder / n, args.columns or None, args.half_window, args.min_speed) for n in names]
    print(f"\n{args.folder}: motor-current noise per joint, A (joints 1..6); local quadratic over "
          f"±{args.half_window} rows, speeds >= {args.min_speed} rad/s\n")
    print(f"{'recording':34s} {'rows':>6s} {'drop':>4s}  {'σ local fit (robust)':>41s}  "
          f"{'σ local fit (plain std)':>41s}  {'σ actual−target':>41s}")
    for r in results:
        print(f"{r.source:34s} {r.rows:6d} {r.dropped:4d}  {fmt(r.local_fit_a)}  {fmt(r.local_fit_std_a)}  "
              f"{fmt(r.actual_minus_target_a)}")
    all_local = np.array([r.local_fit_a for r in results])
    print(f"\n{'median over recordings':34s} {'':>11s}  {fmt(np.median(all_local, axis=0))}")
    print(f"{'largest over recordings':34s} {'':>11s}  {fmt(all_local.max(axis=0))}")
    print(f"{'samples used (min)':34s} {'':>11s}  {fmt(np.min([r.used for r in results], axis=0), '6d')}")
    print(f"{'rms current (median)':34s} {'':>11s}  {fmt(np.median([r.rms_current_a for r in results], axis=0))}")
    print(f"\n{'σ in fast motion (> ' + str(FAST_RAD_S) + ' rad/s), A':34s}")
    for r in results:
        print(f"  {r.source:32s} {'':>11s}  {fmt(r.fast_a)}")
    print(f"{'σ at rest (whole arm still), A':34s}")
    for r in results:
        if np.isfinite(r.at_rest_a).any():
            print(f"  {r.source:32s} {'':>11s}  {fmt(r.at_rest_a)}")
    gap = np.median([r.median_gap_ms for r in results])
    print(f"\nwhiteness: half the mean square difference of raw rows k apart / σ² (1 = white; median gap {gap:.0f} ms)")
    for b, k in enumerate(LAGS_ROWS):
        print(f"  k = {k} {'':>37s}  {fmt(np.median([r.whiteness[b] for r in results], axis=0), '6.2f')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
