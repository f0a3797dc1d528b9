"""What binds ``plan --target-std`` on a shipped simulated robot: each candidate's predicted σ, term by term (issue 22).

Not a test: it prints a table. One seed's state is prepared as ``benchmarks.seeded_runs`` prepares it (with
``--calibrate``: a drive-gain calibration run first, whose empty run is also the stored baseline the noise is
measured in), the plan's noise model is read as ``plan --target-std`` reads it (``session.target.noise_for``),
and for the grid's candidates nearest the target within ``--max-s`` of procedure (the approach move left out:
it depends on where the robot stands) and the one ``plan`` chooses, it prints the procedure's robot time, its
constant-speed seconds (loaded run, both legs), and σ of the mass and of the centre of mass (largest axis) as
the terms of ``design.covariance_terms`` are added one by one: the noise alone, + the wrist torques, + the
drive gains, + the DH lengths, + the joint zeros, + the residual friction, + the shared baseline's correlation
(negative; 0 unless the candidate's run subtracts the calibration's empty run), + the torque-gain term of the
clusters standing at the calibration's angles (``planned_scatter``) (= the root of the run's expected
variance; the plan's σ is the median over the draws of the wrist term and of the run's own noise estimate: the
last columns, with their spread and P over). The last
columns are the information per second, σ m (noise alone) · √(constant-speed s), and the constant-speed
seconds the candidate's shape would need for the target mass given its other terms (∞: they alone exceed it).

    .venv/bin/python -m benchmarks.plan_budget --robot sim-ec66 [--seed 1] [--target-std 2,1] [--max-s 15]
        [--rows 6] [--procedure NAME] [--calibrate [--calibrate-with KG:X,Y,Z] [--calibrate-speed PERCENT]
        [--calibrate-procedure NAME|FILE]] [--retry-sweeps N]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.seeded_runs import parse_reference, seed_config  # noqa: E402
from payload_agent.evaluation import design  # noqa: E402
from payload_agent.evaluation.calibration import effective_calibration  # noqa: E402
from payload_agent.session import target as targets  # noqa: E402
from payload_agent.solvers.wls import cog_with_covariance  # noqa: E402

# the order the terms are added in (each column: this one and all before it)
ORDER = ("noise", "wrist", "gains", "lengths", "zeros", "friction", "baseline", "scatter")


def sigmas(theta: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """(σ mass g, σ centre of mass mm, largest axis) of a covariance of θ = [m, m·c]."""
    _, cov_c = cog_with_covariance(theta, cov)
    return 1000.0 * math.sqrt(max(cov[0, 0], 0.0)), 1000.0 * math.sqrt(max(float(np.max(np.diag(cov_c))), 0.0))


def budget(config, c: design.Candidate, noise: design.NoiseModel, theta: np.ndarray, target_g: float) -> dict:
    """One candidate's procedure s, constant-speed s (both legs), cumulative σ per ``ORDER`` and the bound columns."""
    plan = design.plan_for(config, c)
    shared = noise.shared_baseline is not None and noise.shared_baseline.reused_by(design.run_config(config, c))
    terms, n = design.covariance_terms(design.with_candidate(config, c), plan, noise, theta, shared=shared)
    cumulative, total = [], np.zeros((4, 4))
    for name in ORDER:
        total = total + terms[name]
        cumulative.append(sigmas(theta, total))
    # both legs of every bidirectional sweep are recorded; the planned samples are one leg's
    legs = 2.0 if config.procedure.bidirectional else 1.0
    const_s = legs * n * noise.sample_period_s
    noise_m = sigmas(theta, terms["noise"])[0]
    rest_sq = cumulative[-1][0] ** 2 - noise_m ** 2
    needed = noise_m ** 2 * const_s / (target_g ** 2 - rest_sq) if target_g ** 2 > rest_sq else math.inf
    return {"candidate": c, "procedure_s": design.robot_time_s(plan), "const_s": const_s, "cumulative": cumulative,
            "per_root_s": noise_m * math.sqrt(const_s), "const_s_needed": needed}


def spread(q: design.Prediction) -> str:
    """The standard deviation of the σ a run reports over the plan's draws (wrist term and the run's own noise
    estimate), in % of the typical run's."""
    if q.draws is None:
        return "-"
    return f"{100 * np.std(q.draws[:, 0]) / q.mass_std_g:.1f} / {100 * np.std(q.draws[:, 1]) / q.cog_std_mm:.1f} %"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", default="sim-ec66", help="a shipped simulated robot (configs/NAME.yaml)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--target-std", default="2,1", metavar="G,MM")
    p.add_argument("--max-s", type=float, default=15.0, help="procedure seconds of the candidates shown")
    p.add_argument("--rows", type=int, default=6, help="candidates shown (nearest the target first)")
    p.add_argument("--calibrate", action="store_true", help="calibrate the drive gains first")
    p.add_argument("--calibrate-with", metavar="KG:X,Y,Z", help="the calibration's reference (default 3:0,0,80)")
    p.add_argument("--calibrate-speed", type=float, metavar="PERCENT", help="the calibration's sweep speed")
    p.add_argument("--calibrate-procedure", metavar="NAME|FILE",
                   help="the calibration's procedure (as `calibrate --procedure`; default the YAML's)")
    p.add_argument("--procedure", metavar="NAME", help="show only this procedure's candidates (and the chosen one)")
    p.add_argument("--retry-sweeps", type=int, default=0, metavar="N",
                   help="the calibration run's retries of a failed sweep (a loaded host), as seeded_runs")
    args = p.parse_args(argv)
    grams, mm = targets.parse_target(args.target_std)
    with tempfile.TemporaryDirectory(prefix="plan-budget-") as tmp:
        config = seed_config(args.robot, args.seed, Path(tmp), args.calibrate, parse_reference(args.calibrate_with),
                             args.calibrate_speed, args.retry_sweeps, calibrate_procedure=args.calibrate_procedure)
        noise, source = targets.noise_for(config)
        cal = effective_calibration(config) if args.calibrate else None
        sim = config.simulation
        theta = design.nominal_theta(sim.payload.mass_kg, sim.payload.cog_mm)
        choice = design.choose(config, grams, mm, noise, nominal_mass_kg=sim.payload.mass_kg,
                               nominal_cog_mm=sim.payload.cog_mm,
                               exhaustive=args.procedure is not None)
        near = sorted((q for q in choice.table if q.usable and q.robot_time_s <= args.max_s + 0.05
                       and args.procedure in (None, q.candidate.procedure)),
                      key=lambda q: max(q.mass_std_g / grams, q.cog_std_mm / mm))[:args.rows]
        shown = near + ([choice.best] if choice.best is not None and choice.best not in near else [])
        rows = [(q, budget(config, q.candidate, noise, theta, grams)) for q in shown]
    calibrated = f", calibrated on {args.calibrate_procedure or 'the YAML procedure'}" if args.calibrate else ""
    print(f"{args.robot}, seed {args.seed}{calibrated}: {source}")
    if cal is not None:
        print("the calibration's gains: " + ", ".join(
            f"joint {j + 1} ±{100 * cal.scale_std[j]:.3f} %" for j in cal.fitted_joints) + " fitted, others nominal")
    print(f"target {grams:g} g / {mm:g} mm for the simulation's payload; chosen: "
          + (f"{choice.best.candidate.describe()} ({choice.best.robot_time_s:.1f} s)" if choice.best else "none"))
    head = " | ".join(("noise", "+ wrist", "+ gains", "+ DH lengths", "+ zeros", "+ friction (plan)",
                       "+ shared baseline", "+ gain scatter (corrected clusters)"))
    print(f"\n| candidate | procedure s | constant-speed s | {head} | σ m·√s (noise) | constant-speed s for "
          f"{grams:g} g | a typical run (median) | run-to-run spread m / c | P over |\n|" + "---|" * 16)
    for q, b in rows:
        mark = " (chosen)" if choice.best is not None and q is choice.best else ""
        cells = " | ".join(f"{m:.2f} / {c:.2f}" for m, c in b["cumulative"])
        print(f"| {q.candidate.describe()}{mark} | {b['procedure_s']:.1f} | {b['const_s']:.1f} | {cells} | "
              f"{b['per_root_s']:.2f} g·√s | {b['const_s_needed']:.1f} | {q.mass_std_g:.2f} / {q.cog_std_mm:.2f} | "
              f"{spread(q)} | {100 * q.p_over(grams, mm):.0f} % |")
        if abs(b["cumulative"][-1][0] - q.mass_rms_std_g) > 1e-6 * max(q.mass_rms_std_g, 1.0):
            print(f"  (!) the terms add to {b['cumulative'][-1][0]:.3f} g, the plan's root mean square is "
                  f"{q.mass_rms_std_g:.3f} g")

    return 0


if __name__ == "__main__":
    sys.exit(main())
