"""What declaring the tool cable (``robot.tool_cable_fitted``) does to σ, on arms with and without one (issue 22).

Not a test: it prints numbers. Each case of the accuracy benchmark (same arm, payload, procedure and calibration:
``sigma_budget.analysed_case``) is analysed once per declaration by the agent's own analysis
(``remedies.comp_estimate``) on the same recorded data (``--declarations``): undeclared, where the cable spring's
presence test weights its term ((T − E₀T)⁺/T below the test's quantile); declared, where the fitted spring's effect
comes off the result and its noise goes into σ (``systematics.cable_spring.term``, session 21); declared none
(``robot.tool_cable_fitted: false``, session 26), no term below the test, the whole measured effect above it. Per
scenario it prints rms(err/σ) of the mass and each CoM axis and the 95 % coverage of the mass interval and the CoM
ellipsoid per declaration (and how many cases found a cable the YAML declares absent). On an arm with a cable the
declared term should bring the rms to 1; on one without, what it costs is the price of declaring a cable that is not
there; declaring none on an arm with one is the price of the user being wrong.

    .venv/bin/python -m benchmarks.cable_declared [--scenarios realistic,hard] [--payloads 12] [--speed 10 |
        --procedure speed=10,travel=20,accel=20,sweep=0:55] [--solver general|three-step]
        [--declarations undeclared,declared,declared none]
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


# the columns: ``robot.tool_cable_fitted`` absent (None), true, and false (session 26: the user declares no cable)
DECLARATIONS = {"undeclared": None, "declared": True, "declared none": False}


def z_scores(scenario: str, index: int, proc: cases.Procedure, n_payloads: int, solver: str,
             declarations=("undeclared", "declared")) -> list[dict]:
    """A row per declaration of one case (``cases._row``: z_mass, z_cog, coverage; ``cable_found``: the note of a
    cable the test found although the YAML declares none)."""
    c = analysed_case(scenario, index, proc, n_payloads)
    kin_kw = {"length_std_m": cases.declared_length_std_mm(scenario) / 1000.0}
    unfitted = cases.declared_unfitted_gain_std(scenario)
    rows = []
    for name in declarations:
        est, _ = comp_estimate(c["loaded"], c["empty"], c["ref"], with_cable(c["draws"]["declared"], DECLARATIONS[name]),
                               c["config"], unfitted, kin_kw, solver, c["mount"])
        rows.append(cases._row({"cable_found": any("although the robot YAML declares none" in n for n in est.notes)},
                               est, c["mass"], c["cog"], 0.0))
    return rows


def summary(rows: list[dict]) -> str:
    z = np.array([[r["z_mass"], *r["z_cog"]] for r in rows], float)
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    cover = (np.mean([bool(r["mass_in_ci95"]) for r in rows]), np.mean([bool(r["cog_in_ci95"]) for r in rows]))
    found = sum(bool(r.get("cable_found")) for r in rows)
    return (f"{' / '.join(f'{v:.2f}' for v in rms)} | {cover[0]:.2f} / {cover[1]:.2f}"
            + (f" (found {found} of {len(rows)})" if found else ""))


def main(argv: list[str] | None = None) -> int:
    from benchmarks.accuracy import add_procedure_arguments, speed_or_procedure

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="realistic,hard", help="comma-separated (benchmarks.cases.ALL_SCENARIOS)")
    p.add_argument("--payloads", type=int, default=12)
    add_procedure_arguments(p)
    p.add_argument("--solver", choices=("general", "three-step"), default="general")
    p.add_argument("--declarations", default="undeclared,declared",
                   help=f"comma-separated columns, from {', '.join(DECLARATIONS)}")
    args = p.parse_args(argv)
    names = args.declarations.split(",")
    if set(names) - set(DECLARATIONS):
        p.error(f"unknown declarations {sorted(set(names) - set(DECLARATIONS))}; known: {', '.join(DECLARATIONS)}")
    proc = speed_or_procedure(p, args.speed, args.procedure)
    print(f"\n{proc.describe()}, {args.solver}, {args.payloads} payloads: rms(err/σ) m / x / y / z | in 95 % m / c")
    print(f"| scenario | {' | '.join(names)} |\n|---|{'---|' * len(names)}")
    for scenario in args.scenarios.split(","):
        if scenario not in cases.ALL_SCENARIOS:
            p.error(f"unknown scenario {scenario!r}; known: {', '.join(cases.ALL_SCENARIOS)}")
        per_case = [z_scores(scenario, i, proc, args.payloads, args.solver, names) for i in range(args.payloads)]
        print(f"| {scenario} | " + " | ".join(summary([rows[k] for rows in per_case]) for k in range(len(names)))
              + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
