"""How far the cable spring's stiffness estimate lies from the simulated cable, in its own σ (issue 22, session 14).

Not a test: it prints one row per case of the accuracy benchmark's general-bi-cal-comp (``sigma_budget.analysed_case``:
same arm, payload, procedure and calibration) with (κ̂ − κ_true)/σ per wrist joint and whether the presence test
found the cable, fitted twice on the same data: with the still joints' nuisance gain columns measured relative to
their own joint's rows (as before session 14) and with what the drive-gain calibration absorbed of each cluster on
every row of its joint (``wrist.columns(gain_reference=…)``, what the analysis does now). An honest κ̂ has
(κ̂ − κ_true)/σ of mean 0 and rms 1; a bias there is a path the spring's covariance lacks.

    .venv/bin/python -m benchmarks.cable_stiffness [--scenario hard] [--payloads 12] [--speed 10 | --procedure SPEC]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402
from benchmarks.sigma_budget import analysed_case  # noqa: E402


def standardised(scenario: str, index: int, proc: cases.Procedure, n_payloads: int
                 ) -> list[tuple[np.ndarray, bool]]:
    """[(κ̂ − κ_true)/σ per wrist joint with a lever, found?] without and with the calibration's absorption."""
    from payload_agent.evaluation.systematics import cable_spring, offsets

    c = analysed_case(scenario, index, proc, n_payloads)
    model = c["model"]
    by_name = {d.key.name: d for d in model.sweeps}
    labels = sorted({offsets.wrist_joint(g, by_name[g.sweep]) for g in model.groups} - {None})
    effects = c["draws"]["effects"]
    truth = np.zeros(3) if effects is None else np.asarray(effects.tool_cable.stiffness_nm_per_rad, float)
    out = []
    for reference in (None, c["cal"].reference):
        s = cable_spring.fit_spring(model, labels, c["mount"], gain_reference=reference)
        if s is None:
            continue
        z = (s.estimate - truth[[j - 3 for j in s.joints]]) / np.sqrt(np.diag(s.cov))
        out.append((z, s.present))
    return out


def main(argv: list[str] | None = None) -> int:
    from benchmarks.accuracy import add_procedure_arguments, speed_or_procedure

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="hard", help="benchmarks.cases.ALL_SCENARIOS")
    p.add_argument("--payloads", type=int, default=12)
    add_procedure_arguments(p)
    args = p.parse_args(argv)
    if args.scenario not in cases.ALL_SCENARIOS:
        p.error(f"unknown scenario {args.scenario!r}; known: {', '.join(cases.ALL_SCENARIOS)}")
    proc = speed_or_procedure(p, args.speed, args.procedure)
    rows = [standardised(args.scenario, i, proc, args.payloads) for i in range(args.payloads)]
    rows = [r for r in rows if len(r) == 2]
    print(f"\n{args.scenario}, {proc.describe()}: (κ̂ − κ_true)/σ per wrist joint, relative | absolute nuisance gains")
    print("| case | relative | found | absolute | found |\n|---|---|---|---|---|")
    for i, ((z0, f0), (z1, f1)) in enumerate(rows):
        print(f"| {i} | {' / '.join(f'{v:+.2f}' for v in z0)} | {f0} | {' / '.join(f'{v:+.2f}' for v in z1)} | {f1} |")
    for k, name in ((0, "relative"), (1, "absolute")):
        Z = np.array([r[k][0] for r in rows])
        print(f"{name}: mean {' / '.join(f'{v:+.2f}' for v in Z.mean(0))}, rms "
              f"{' / '.join(f'{v:.2f}' for v in np.sqrt((Z ** 2).mean(0)))}, found {sum(r[k][1] for r in rows)} "
              f"of {len(rows)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
