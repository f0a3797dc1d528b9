"""Does evaluation/design's predicted σ match what runs report, and the errors they reach? (issue 14, item 4)

Not a test: it prints a table. For each sweep speed, every seeded payload is run through the accuracy
benchmark's cases (realistic scenario, ``general-bi-cal``) and its σ is predicted beforehand by
``evaluation.design.predict`` from the plan, the regressor, the benchmark's effort noise (0.3 N·m at 8 ms)
and the same systematic terms the run declares (DH lengths; the calibration's gain uncertainty of that
case). Columns: mean predicted σ, mean reported σ, their ratio, and the RMS of the actual errors.

    .venv/bin/python -m benchmarks.design_check [--payloads N] [--speeds 3,5,10,20] [--jobs 2]
        [--procedure j2_triple] [--travel 25] [--accel 100] [--sweep-deg 0:20]

``--procedure`` runs another procedure file (bundled name or path) instead of the benchmark
config's paper_bd: the cases are recorded with it (benchmarks.cases' config with its procedure
name replaced in this process), and the prediction is made for the same candidate.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402


def use_procedure(name: str) -> None:
    """Make benchmarks.cases record with procedure ``name`` (in this process; "" = its own)."""
    import dataclasses

    original = getattr(cases, "_design_check_original_config", cases._config)
    cases._design_check_original_config = original

    def config(proc, bidirectional):
        c = original(proc, bidirectional)
        return dataclasses.replace(c, procedure=dataclasses.replace(c.procedure, name=name)) if name else c

    cases._config = config


def one(args) -> dict:
    speed, index, mass, cog, knobs = args
    from payload_agent.evaluation import design

    name, travel, accel, lo, hi = knobs
    use_procedure(name)
    proc = cases.Procedure(f"{name}{speed:g}", speed, travel, accel, lo, hi)
    rows = cases.run_case(("realistic", proc, ("general-bi-cal",), index, mass, cog))
    row = rows[0]
    if "error" in row:
        return {"speed": speed, "error": row["error"]}
    _, _, config = cases.plans(proc)
    noise = design.NoiseModel((cases.NOISE_NM,) * 6, cases.TICK_S, gain_rel_std=tuple(row["gain_rel_std"]),
                              length_std_m=row["length_std_mm"] / 1000.0,
                              gain_reference=(cases.theta_reference(), tuple(row["fitted_joints"])))
    cand = design.Candidate(speed, travel, lo, hi, 1, accel, name)
    pred = design.predict(config, cand, noise, design.nominal_theta(mass, cog), check_safety=False)
    return {"speed": speed, "pred_m": pred.mass_std_g, "pred_c": pred.cog_std_mm, "rep_m": row["mass_std_g"],
            "rep_c": max(row["cog_std_mm"]), "err_m": row["mass_err_g"], "err_c": row["cog_err_mm"],
            "time_s": pred.robot_time_s, "gate": bool(row.get("gate_passed")),
            "in95_m": bool(row.get("mass_in_ci95")), "in95_c": bool(row.get("cog_in_ci95"))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--payloads", type=int, default=10)
    p.add_argument("--speeds", default="3,5,10,20")
    p.add_argument("--jobs", type=int, default=0)
    p.add_argument("--procedure", default="", help="procedure name or file (default: the benchmark config's)")
    p.add_argument("--travel", type=float, default=25.0)
    p.add_argument("--accel", type=float, default=40.0)
    p.add_argument("--sweep-deg", default="0:55", metavar="FROM:TO")
    p.add_argument("--payload", metavar="KG:X,Y,Z",
                   help="one tool for every case (each case keeps its own robot draws), e.g. 2:40,-25,70 "
                        "(the sim config's); default: the benchmark's seeded payloads")
    args = p.parse_args(argv)
    speeds = [float(v) for v in args.speeds.split(",")]
    lo, hi = (float(v) for v in args.sweep_deg.split(":"))
    knobs = (args.procedure, args.travel, args.accel, lo, hi)
    tools = cases.payloads(args.payloads)
    if args.payload:
        kg, xyz = args.payload.split(":")
        tools = [(float(kg), tuple(float(v) for v in xyz.split(",")))] * args.payloads
    todo = [(s, i, m, c, knobs) for s in speeds for i, (m, c) in enumerate(tools)]
    with ProcessPoolExecutor(max_workers=args.jobs or None) as pool:
        out = list(pool.map(one, todo, chunksize=1))
    print(f"procedure {args.procedure or 'paper_bd (benchmark config)'}, travel {args.travel:g} %, "
          f"accel {args.accel:g} %, sweep {lo:g}–{hi:g}°, {args.payloads} "
          f"{'cases of the tool ' + args.payload if args.payload else 'payloads'}, realistic, general-bi-cal")
    print("| speed % | robot s | pred σm g | reported σm g | ratio m | rms Δm g | mean |Δm| g | "
          "pred σc mm (max axis) | reported σc mm | ratio c | rms Δc/√3 mm | mean Δc mm | in 95 % m / c | gate pass | failed |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for s in speeds:
        rs = [r for r in out if r["speed"] == s and "error" not in r]
        if not rs:
            continue
        f = lambda k: np.array([r[k] for r in rs])  # noqa: E731
        print(f"| {s:g} | {f('time_s').mean():.0f} | {f('pred_m').mean():.2f} | {f('rep_m').mean():.2f} | "
              f"{f('pred_m').mean() / f('rep_m').mean():.2f} | {np.sqrt(np.mean(f('err_m') ** 2)):.2f} | "
              f"{np.mean(np.abs(f('err_m'))):.2f} | "
              f"{f('pred_c').mean():.2f} | {f('rep_c').mean():.2f} | {f('pred_c').mean() / f('rep_c').mean():.2f} | "
              f"{np.sqrt(np.mean(f('err_c') ** 2) / 3):.2f} | {f('err_c').mean():.2f} | "
              f"{f('in95_m').mean():.2f} / {f('in95_c').mean():.2f} | {f('gate').mean():.2f} | "
              f"{len([r for r in out if r['speed'] == s]) - len(rs)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
