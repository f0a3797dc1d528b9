"""Is σ calibrated beyond one noise draw? rms(err/σ) over several sensor-noise draws of every benchmark case.

Not a test: it prints numbers. The accuracy benchmark draws the sensor noise once per (payload, procedure), and
its clean ablation rows share that draw, so a cell's rms(err/σ) over 24 payloads is one sample that scatters by
about ±0.28 (95 %) around the truth. Here each case (same simulated arm, payload, drifts and effects as
``benchmarks.accuracy``) is re-run with ``--replicas`` further noise draws (``cases.run_case``'s replica), and
per quantity (mass, each CoM axis) it prints the pooled rms(err/σ) and 95 % coverage over all draws, and its two
parts: rms over payloads of (spread over the draws / mean σ), how well σ sizes the noise, and of (mean error /
σ, less the noise the mean of a few draws still carries), the systematic part; rms² ≈ noise² + systematic².

    .venv/bin/python -m benchmarks.noise_replicas --scenario realistic --method three-step-bi-cal-comp \\
        --payloads 24 --replicas 4 [--speed 10 | --procedure speed=10,travel=20,accel=20,sweep=0:55]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402
from benchmarks.remedies import COMP, COMP3  # noqa: E402

Z95 = 1.959964


def draws_of(scenario: str, proc: cases.Procedure, method: str, index: int, n_payloads: int,
             replicas: int) -> np.ndarray:
    """(replicas + 1, 4, 2): per noise draw (0: the accuracy benchmark's own) the error and σ of m (kg) and c (m)."""
    mass, cog = cases.payloads(n_payloads)[index]
    out = []
    for r in range(replicas + 1):
        row = cases.run_case((scenario, proc, (method,), index, mass, cog, None, None, r))[0]
        if "error" in row:
            raise SystemExit(f"case {index}, draw {r}: {row['error']}")
        err = [row["mass_err_g"] / 1000.0, *((np.asarray(row["est_cog_mm"]) - np.asarray(cog)) / 1000.0)]
        std = [row["mass_std_g"] / 1000.0, *(np.asarray(row["cog_std_mm"]) / 1000.0)]
        out.append(np.column_stack([err, std]))
    return np.array(out)


def summary(per_case: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Pooled rms(err/σ) and coverage per quantity, and the noise and systematic parts (module docstring)."""
    z = np.concatenate([d[:, :, 0] / d[:, :, 1] for d in per_case])
    spread = np.array([d[:, :, 0].std(axis=0, ddof=1) / d[:, :, 1].mean(axis=0) for d in per_case])
    mean = np.array([d[:, :, 0].mean(axis=0) / d[:, :, 1].mean(axis=0) for d in per_case])
    # the mean over R draws still carries the noise's spread²/R: taken out so that noise² + systematic² ≈ rms²
    bias2 = mean ** 2 - spread ** 2 / per_case[0].shape[0]
    return {"rms": np.sqrt(np.mean(z ** 2, axis=0)), "in95": np.mean(np.abs(z) <= Z95, axis=0),
            "noise": np.sqrt(np.mean(spread ** 2, axis=0)),
            "systematic": np.sqrt(np.maximum(np.mean(bias2, axis=0), 0.0)),
            "draws": np.array(len(z))}


def main(argv: list[str] | None = None) -> int:
    from benchmarks.accuracy import add_procedure_arguments, speed_or_procedure

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="realistic", help="one of benchmarks.cases.ALL_SCENARIOS")
    p.add_argument("--method", default=COMP3, choices=(COMP, COMP3))
    p.add_argument("--payloads", type=int, default=24)
    p.add_argument("--replicas", type=int, default=4, help="noise draws per case besides the benchmark's own")
    add_procedure_arguments(p)
    args = p.parse_args(argv)
    if args.scenario not in cases.ALL_SCENARIOS:
        p.error(f"unknown scenario {args.scenario!r}; known: {', '.join(cases.ALL_SCENARIOS)}")
    if args.replicas < 1 or args.payloads < 2:
        p.error("--replicas must be at least 1 and --payloads at least 2")
    proc = speed_or_procedure(p, args.speed, args.procedure)
    per_case = [draws_of(args.scenario, proc, args.method, i, args.payloads, args.replicas)
                for i in range(args.payloads)]
    s = summary(per_case)
    print(f"{args.scenario}, {proc.describe()}, {args.method}: {args.payloads} payloads × {args.replicas + 1} noise "
          f"draws ({int(s['draws'])})")
    print("| quantity | rms(err/σ) | in 95 % | noise: spread / σ | systematic: mean error / σ |")
    print("|---|---|---|---|---|")
    for k, name in enumerate(("m", "x", "y", "z")):
        print(f"| {name} | {s['rms'][k]:.2f} | {s['in95'][k]:.2f} | {s['noise'][k]:.2f} | {s['systematic'][k]:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
