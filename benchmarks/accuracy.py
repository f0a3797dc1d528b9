"""Accuracy benchmark: simulated EC66, seeded payloads, six methods, four scenarios, four speeds.

Not a test: it prints numbers. Run ``.venv/bin/python -m benchmarks.accuracy [--quick] [--json PATH]
[--plot PATH] [--default-procedure SPEC]``; ``--help`` lists every option.

For speed the simulated robot is driven directly (no sockets, no clock thread): the
planner's moves go to ``SimRobot.move_joints`` and ``SimRobot.step()`` is called until
each move ends (``fakes.offline.record_plan``); the states of every sweep become
``SweepData`` exactly as the recorder's CSV would after unit conversion. Then the agent's
own pipeline runs: ``delta.subtract_all`` -> ``combine.add_combined`` -> solvers, and the quality
gate (``quality.evaluate``) on each PTP method's result: column "gate pass", the fraction of cases
it would let through to the controller (``gate_failures`` in --json: which checks refused).

Each case is one payload on one simulated robot (its DH errors, drive-gain errors and
friction drifts are drawn from the payload index and scenario, so every procedure sees the
same robot). It records the bidirectional plan for the empty flange, for the tool and, for
``general-bi-cal``, for the calibration reference payload (3.0 kg at (0, 0, 80) mm, its own
friction drift draw, the same empty-flange baseline). The unidirectional methods use only
the "up" sweeps, which are sampled exactly as the unidirectional plan would sample them
(each up sweep starts from standstill at the same start pose); the motion time reported for
them is the unidirectional plan's.

Scenarios
  ideal      sensor noise 0.3 N·m, constant Coulomb + viscous friction, exact gains and DH.
  realistic  ideal + load-dependent Coulomb (5 % of the load torque), friction scale drift
             ±10 % between the empty and each loaded run, drive gains off by up to ±3 % per
             joint (the measured torque is multiplied), the simulated arm's DH lengths off by
             up to 0.5 mm (ArmSpec.with_dh_errors, uniform) while the agent uses the nominal ones.
  hard       realistic + every error source of a real arm in the physics core (fakes/effects.py):
             angle noise, timestamp jitter, joint zero offsets, gear elasticity, torque ripple,
             asymmetric Coulomb friction, friction lower in a warmer tool run, effort quantisation,
             a weak tool cable (benchmarks/hard.py has the magnitudes; docs/sources.md the sources)
  hard-strong-cable  hard with a strong tool cable: the quality gate must refuse the result
Ablations (``--scenarios``): realistic-exact-gains (realistic with exact drive gains) and
realistic+EFFECT, one physics-core effect at a time (benchmarks/hard.ABLATION_SCENARIOS).
Declared kinematic uncertainty (``--length-uncertainty-mm``): what the agent is told about its DH
lengths, propagated into the general solver's σ. By default it matches each scenario's simulated
arm, as a correctly configured agent would: 0 in "ideal" (exact lengths), 0.5/√3 ≈ 0.29 mm in the
realistic scenarios (the standard deviation of a uniform ±0.5 mm error).
Declared drive-gain uncertainty of the joints the calibration does not fit
(``--unfitted-gain-uncertainty-percent``; ``general-bi-cal`` only): the agent's
``GainCalibration.gain_rel_std(unfitted=...)``, whose default is ``UNFITTED_GAIN_REL_STD`` (3 %).
Like the DH lengths, by default it matches each scenario's simulated arm: 0 in "ideal" and
"realistic-exact-gains" (exact gains), 3/√3 ≈ 1.73 % in "realistic" (uniform ±3 %).
Methods
  three-step      the paper's solver, "up" sweeps only (as published)
  general-up      weighted least squares, "up" sweeps only
  general-bi      weighted least squares on up/down sweeps combined at matching angles
  general-bi-cal  general-bi after a drive-gain calibration (agent/calibration.py) with the
                  reference payload on the same robot, same procedure
  general-bi-cal-comp  general-bi-cal plus the remedies for a real arm (benchmarks/remedies.py): the
                  declared joint stiffness compensated, stiffness, zero-offset, residual-friction and
                  wrist-torque uncertainty in σ, the tool-cable check in the quality gate
  dynamic         the paper's §3.4 baseline (eq. 29): loaded − empty along a 5th-order Fourier
                  excitation trajectory of joints 4–6 (benchmarks/excitation.py, solvers/dynamic.py);
                  speed-independent, reported once per scenario in the row "excitation"
Procedures
  speed rows     sweep 1, 5, 10, 20 % of 144 °/s, travel 10 %, acceleration 20 %, 0–55° (pinned:
                 the sim config's procedure when the benchmark was set up)
  "default"      the recommended procedure, RECOMMENDED_DEFAULT (``--default-procedure``)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.cases import (ALL_SCENARIOS, DH_ERROR_MM, GAIN_ERROR, METHODS, PTP_METHODS,  # noqa: E402
                              RECOMMENDED_DEFAULT, ROOT, SCENARIOS, SPEED_ROW_ACCEL, SPEED_ROW_TRAVEL, SPEEDS,
                              SWEEP_DEG, Procedure, _dispatch, check_safety, declared_length_std_mm,
                              declared_unfitted_gain_std, payloads)
from benchmarks.tables import DEFAULT_LABEL, format_table, plot, summarize  # noqa: E402

def parse_procedure(text: str, label: str, base: Procedure) -> Procedure:
    """'speed=8,travel=25,accel=40,sweep=0:55' -> Procedure (unspecified fields from ``base``)."""
    values = dataclasses.asdict(base)
    values["label"] = label
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, _, val = part.partition("=")
        if key == "sweep":
            lo, _, hi = val.partition(":")
            values["sweep_from"], values["sweep_to"] = float(lo), float(hi)
        elif key in ("speed", "travel", "accel"):
            values[key] = float(val)
        else:
            raise ValueError(f"unknown procedure setting {key!r} (speed, travel, accel, sweep=FROM:TO)")
    return Procedure(**values)


def add_procedure_arguments(parser: argparse.ArgumentParser) -> None:
    """``--speed`` and ``--procedure SPEC``: the one procedure of a benchmark that studies one (sigma_budget,
    noise_replicas, the cable benchmarks); ``speed_or_procedure`` reads them."""
    parser.add_argument("--speed", type=float, default=10.0,
                        help="sweep speed, percent (travel 10 %%, accel 20 %%, 0–55°)")
    parser.add_argument("--procedure", metavar="SPEC", help="instead of --speed: e.g. the accuracy benchmark's "
                        f"default, {RECOMMENDED_DEFAULT} (speed, travel, accel in %%, sweep=FROM:TO in deg)")


def speed_or_procedure(parser: argparse.ArgumentParser, speed: float, spec: str | None) -> Procedure:
    """The one procedure of a ``--speed`` / ``--procedure SPEC`` command line (sigma_budget, noise_replicas): the
    speed row's (travel, acceleration, range) at ``speed`` %, or ``spec`` over it; a bad spec is the parser's error."""
    proc = Procedure(f"{speed:g}", speed, SPEED_ROW_TRAVEL, SPEED_ROW_ACCEL, *SWEEP_DEG)
    try:
        return parse_procedure(spec, "default", proc) if spec else proc
    except ValueError as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="3 payloads at 5 %% speed, the four main scenarios (< 2 min)")
    p.add_argument("--payloads", type=int, default=20, help="number of seeded payloads (default 20)")
    p.add_argument("--speeds", help="comma-separated sweep speed percentages (default 1,5,10,20; quick: 5; "
                   "'none' for no speed rows)")
    p.add_argument("--travel", type=float, default=SPEED_ROW_TRAVEL,
                   help=f"travel speed %% between sweeps for the speed rows (default {SPEED_ROW_TRAVEL:g})")
    p.add_argument("--accel", type=float, default=SPEED_ROW_ACCEL,
                   help=f"acceleration %% for the speed rows (default {SPEED_ROW_ACCEL:g})")
    p.add_argument("--sweep-deg", default=f"{SWEEP_DEG[0]:g}:{SWEEP_DEG[1]:g}",
                   help="sweep range FROM:TO in degrees of link elevation for the speed rows")
    p.add_argument("--default-procedure", metavar="SPEC",
                   help=f"rows labelled 'default' for this procedure (default {RECOMMENDED_DEFAULT}, "
                   "not with --quick; 'none' for no such rows); speed, travel, accel in %%, sweep=FROM:TO in deg")
    p.add_argument("--scenarios", help=f"comma-separated, from {', '.join(ALL_SCENARIOS)} (default: "
                   f"{', '.join(SCENARIOS)})")
    p.add_argument("--methods", help=f"comma-separated, from {', '.join(METHODS)} (default: all)")
    p.add_argument("--length-uncertainty-mm", type=float, default=None, metavar="MM",
                   help="DH-length standard uncertainty the agent declares, every scenario (default: the "
                   f"simulated arm's own: 0 ideal, {DH_ERROR_MM:g}/√3 mm realistic)")
    p.add_argument("--unfitted-gain-uncertainty-percent", type=float, default=None, metavar="PCT",
                   help="relative drive-gain standard uncertainty general-bi-cal declares for the joints its "
                   "calibration does not fit, every scenario (default: the simulated arm's own: 0 ideal and "
                   f"realistic-exact-gains, {100 * GAIN_ERROR:g}/√3 %% realistic; the agent's default is 3 %%)")
    p.add_argument("--noise-draws", type=int, default=1, metavar="N",
                   help="sensor-noise draws per PTP case (default 1): N > 1 re-runs every case with N − 1 further "
                   "draws on the same arm and payload, so a cell of P payloads holds P × N cases "
                   "(benchmarks.calibration pools them)")
    p.add_argument("--jobs", type=int, default=0, help="worker processes (default: all CPUs)")
    p.add_argument("--json", help="write the summary rows and every case to this path")
    p.add_argument("--plot", help="save the error-vs-speed figure here (e.g. docs/benchmark-error-vs-speed.png)")
    args = p.parse_args(argv)
    n = 3 if args.quick else args.payloads
    if args.speeds == "none":
        speeds: tuple[float, ...] = ()
    else:
        speeds = tuple(float(v) for v in args.speeds.split(",")) if args.speeds else ((5.0,) if args.quick else SPEEDS)
    scenarios = tuple(args.scenarios.split(",")) if args.scenarios else SCENARIOS
    methods = tuple(args.methods.split(",")) if args.methods else METHODS
    for bad, allowed, what in ((scenarios, ALL_SCENARIOS, "scenario"), (methods, METHODS, "method")):
        unknown = [v for v in bad if v not in allowed]
        if unknown:
            p.error(f"unknown {what}(s) {', '.join(unknown)}")
    lo, _, hi = args.sweep_deg.partition(":")
    procs = [Procedure(f"{s:g}", s, args.travel, args.accel, float(lo), float(hi)) for s in speeds]
    default = None
    spec = args.default_procedure or ("none" if args.quick else RECOMMENDED_DEFAULT)
    if spec != "none":
        try:
            default = parse_procedure(spec, DEFAULT_LABEL, parse_procedure(
                RECOMMENDED_DEFAULT, DEFAULT_LABEL, Procedure(DEFAULT_LABEL, 0, 0, 0, 0, 0)))
        except ValueError as exc:
            p.error(str(exc))
        procs.append(default)
    for proc in procs:
        problems = check_safety(proc)
        if problems:
            p.error(f"procedure {proc.describe()} would be refused by the safety gate: {'; '.join(problems)}")
    if args.noise_draws < 1:
        p.error("--noise-draws must be at least 1")
    ptp_methods = tuple(m for m in methods if m in PTP_METHODS)
    pays = payloads(n)
    cases: list[tuple] = []
    if ptp_methods:
        cases += [("ptp", (sc, pr, ptp_methods, i, m, c, args.length_uncertainty_mm,
                           args.unfitted_gain_uncertainty_percent, draw)) for sc in scenarios
                  for pr in procs for i, (m, c) in enumerate(pays) for draw in range(args.noise_draws)]
    if "dynamic" in methods:
        cases += [("dynamic", (sc, i, m, c)) for sc in scenarios for i, (m, c) in enumerate(pays)]

    # longest first: slow sweeps take the most simulated ticks
    def cost(case):
        if case[0] == "dynamic":
            return 3.0
        return 100.0 / case[1][1].speed
    cases.sort(key=cost, reverse=True)
    t0 = time.monotonic()
    rows: list[dict] = []
    with ProcessPoolExecutor(max_workers=args.jobs or None) as pool:
        for r in pool.map(_dispatch, cases, chunksize=1):
            rows.extend(r)
    summary = summarize(rows, ALL_SCENARIOS, METHODS)
    elapsed = time.monotonic() - t0
    print(f"payload-agent accuracy benchmark: EC66 simulator, {n} payloads × {args.noise_draws} noise draw(s), scenarios {', '.join(scenarios)}, "
          f"{len(cases)} cases, {elapsed:.0f} s wall on {args.jobs or 'all'} worker(s)")
    for proc in procs:
        print(f"  procedure {proc.label}: {proc.describe()}")
    print("  declared DH-length standard uncertainty: " + ", ".join(
        f"{sc} {declared_length_std_mm(sc, args.length_uncertainty_mm):.3g} mm" for sc in scenarios))
    if "general-bi-cal" in methods:
        print("  declared gain standard uncertainty of joints the calibration does not fit: " + ", ".join(
            f"{sc} {100 * declared_unfitted_gain_std(sc, args.unfitted_gain_uncertainty_percent):.3g} %"
            for sc in scenarios))
    print(format_table(summary))
    for s in summary:
        if s.get("gate_failures"):
            label = s["procedure"] if "speed_percent" not in s else f"{s['speed_percent']:g} %"
            print(f"  gate failures {s['scenario']} {label} {s['method']}: "
                  + ", ".join(f"{name} ×{n}" for name, n in s["gate_failures"].items()))
    for r in rows:
        if "error" in r:
            print(f"  failed: {r['scenario']} {r['procedure']} {r['method']} payload {r['payload']}: {r['error']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "cases": rows, "elapsed_s": elapsed,
                                               "argv": sys.argv[1:] if argv is None else argv,
                                               "quick": args.quick}, indent=1), encoding="utf-8")
    if args.plot:
        plot(summary, Path(args.plot), None if default is None else default.speed, ALL_SCENARIOS, METHODS)
    return 0


if __name__ == "__main__":
    if __package__ in (None, ""):
        sys.path.insert(0, str(ROOT))
    sys.exit(main())
