"""What declaring the tool cable (``robot.tool_cable_fitted``) does to σ, on arms with and without one (issue 22).

Not a test: it prints numbers. Each case of the accuracy benchmark (same arm, payload, procedure and calibration:
``sigma_budget.analysed_case``) is analysed twice by the agent's own analysis (``remedies.comp_estimate``) on the
same recorded data: undeclared, where the cable spring's presence test weights its term ((T − E₀T)⁺/T below the
test's quantile), and declared, where the fitted spring's effect comes off the result and its noise goes into σ
(``systematics.cable_spring.term``, session 21). Per scenario it prints rms(err/σ) of the mass and each CoM axis and the
95 % coverage of the mass interval and the CoM ellipsoid, both ways. On an arm with a cable the declared term
should bring the rms to 1; on one without, what it costs is the price of declaring a cable that is not there.

    .venv/bin/python -m benchmarks.cable_declared [--scenarios realistic,hard] [--payloads 12] [--speed 10 |
        --procedure speed=10,travel=20,accel=20,sweep=0:55] [--solver general|three-step]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402
from benchmarks.hard import Declared  # noqa: E402
from benchmarks.remedies import comp_estimate  # noqa: E402
from benchmarks.sigma_budget import analysed_case  # noqa: E402


def with_cable(declared: Declared | None, fitted: bool | None) -> Declared:
    """The scenario's declaration with ``robot.tool_cable_fitted`` set (None, the realistic arm: nothing else)."""
    base = Declared(None, 0.0, 0.0) if declared is None else declared
    return dataclasses.replace(base, tool_cable_fitted=fitted)


def z_scores(scenario: str, index: int, proc: cases.Procedure, n_payloads: int, solver: str) -> list[dict]:
    """[undeclared row, declared row] of one case (``cases._row``: z_mass, z_cog, coverage)."""
    c = analysed_case(scenario, index, proc, n_payloads)
    kin_kw = {"length_std_m": cases.declared_length_std_mm(scenario) / 1000.0}
    unfitted = cases.declared_unfitted_gain_std(scenario)
    rows = []
    for fitted in (None, True):
        est, _ = comp_estimate(c["loaded"], c["empty"], c["ref"], with_cable(c["draws"]["declared"], fitted),
                               c["config"], unfitted, kin_kw, solver, c["mount"])
        rows.append(cases._row({}, est, c["mass"], c["cog"], 0.0))
    return rows


def summary(rows: list[dict]) -> str:
    z = np.array([[r["z_mass"], *r["z_cog"]] for r in rows], float)
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    cover = (np.mean([bool(r["mass_in_ci95"]) for r in rows]), np.mean([bool(r["cog_in_ci95"]) for r in rows]))
    return f"{' / '.join(f'{v:.2f}' for v in rms)} | {cover[0]:.2f} / {cover[1]:.2f}"


def main(argv: list[str] | None = None) -> int:
    from benchmarks.accuracy import add_procedure_arguments, speed_or_procedure

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="realistic,hard", help="comma-separated (benchmarks.cases.ALL_SCENARIOS)")
    p.add_argument("--payloads", type=int, default=12)
    add_procedure_arguments(p)
    p.add_argument("--solver", choices=("general", "three-step"), default="general")
    args = p.parse_args(argv)
    proc = speed_or_procedure(p, args.speed, args.procedure)
    print(f"\n{proc.describe()}, {args.solver}, {args.payloads} payloads: rms(err/σ) m / x / y / z | in 95 % m / c")
    print("| scenario | undeclared | declared (robot.tool_cable_fitted) |\n|---|---|---|")
    for scenario in args.scenarios.split(","):
        if scenario not in cases.ALL_SCENARIOS:
            p.error(f"unknown scenario {scenario!r}; known: {', '.join(cases.ALL_SCENARIOS)}")
        pairs = [z_scores(scenario, i, proc, args.payloads, args.solver) for i in range(args.payloads)]
        print(f"| {scenario} | {summary([a for a, _ in pairs])} | {summary([b for _, b in pairs])} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
