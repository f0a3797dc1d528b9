"""The friction and torque-gain scatter terms after a drive-gain calibration on ANOTHER procedure (issue 22 items 1, 3).

Not a test: it prints numbers. The accuracy benchmark calibrates on the run's own procedure and shares the empty
run; ``calibrate --procedure j2_quarter`` then ``run`` on paper_bd (or the reverse) does neither. Each case here is
the accuracy benchmark's seeded EC66 (``cases.robot_draws``: DH, gain and friction-drift draws, the scenario's
effects and declarations): the tool run on the run procedure against an empty run there, and the calibration
(``calibration.fit_from_sweeps``, the benchmark's 3 kg reference at (0, 0, 80) mm, its own friction drift and
effects) on the calibration procedure against an empty run there, its own baseline (not shared). Both solvers go
through the agent's ``analyse`` (``remedies.comp_estimate``) twice: with the calibration as ``calibrate`` stores it
("stored") and with its ``reference_shares`` dropped, as a gains.json from before they were stored reads
("stand-in": the tool run's sweeps standing in for the calibration's in the residual-friction and torque-gain
scatter terms). Rows in ``benchmarks.accuracy``'s JSON (procedure "CAL>RUN", method "<solver> stored|stand-in"), so
``benchmarks.calibration`` gives rms(err/σ) and coverage per cell:

    nice -n 10 .venv/bin/python -m benchmarks.cross_calibration [--scenarios realistic+asymmetry,realistic+ripple]
        [--pairs j2_quarter:paper_bd,paper_bd:j2_quarter] [--payloads 8] [--speed 10] [--jobs 1] [--json PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402
from benchmarks.reference import REFERENCE  # noqa: E402
from benchmarks.remedies import comp_estimate, declaration  # noqa: E402

SOLVERS = ("general", "three-step")


@functools.lru_cache(maxsize=None)
def _plan(name: str, speed: float):
    """(plan, config) of procedure ``name`` at the accuracy benchmark's default knobs and sweep ``speed`` %."""
    from payload_agent.motion.planner import make_plan

    proc = cases.Procedure("x", speed, 20.0, 20.0, *cases.SWEEP_DEG)
    config = cases._config(proc, True)
    config = dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, name=name, inertia=None))
    return make_plan(config), config


def run_case(args: tuple) -> list[dict]:
    scenario, cal_name, run_name, speed, index, mass, cog_mm = args
    from payload_agent.errors import PayloadAgentError
    from payload_agent.evaluation import calibration
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth

    draws = cases.robot_draws(scenario, index)
    run_plan, run_config = _plan(run_name, speed)
    cal_plan, cal_config = _plan(cal_name, speed)
    robot = cases._robot(draws, np.asarray(run_plan.moves[0].target_rad), int(round(speed * 100)) + 104729)
    gain = draws["gain"]
    empty, _ = record_plan(robot, run_plan, torque_scale=gain)
    robot.set_payload(PayloadTruth.point(mass, cog_mm))
    mount = np.asarray(robot.snapshot().q, float)
    robot.set_friction_scale(1.0 + draws["drift_load"])
    loaded, _ = record_plan(robot, run_plan, torque_scale=gain)
    tool_effects = robot.effects
    robot.set_payload(None)
    robot.set_friction_scale(1.0)
    cal_empty, _ = record_plan(robot, cal_plan, torque_scale=gain)
    robot.set_payload(PayloadTruth.point(REFERENCE[0], REFERENCE[1]))
    robot.set_friction_scale(1.0 + draws["drift_ref"])
    if draws["effects_ref"] is not None:
        robot.effects = draws["effects_ref"]
    ref, _ = record_plan(robot, cal_plan, torque_scale=gain)
    robot.effects = tool_effects
    base = {"scenario": scenario, "procedure": f"{cal_name}>{run_name}", "payload": index, "noise_draw": 0,
            "speed_percent": speed}
    kin_kw = {"length_std_m": cases.declared_length_std_mm(scenario) / 1000.0}
    unfitted = cases.declared_unfitted_gain_std(scenario)
    try:
        cal = calibration.fit_from_sweeps(ref, cal_empty, cal_config, REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0,
                                          joints=declaration(draws["declared"]))
    except PayloadAgentError as exc:
        return [dict(base, method=f"{s} {v}", error=str(exc)) for s in SOLVERS for v in ("stored", "stand-in")]
    rows = []
    for solver in SOLVERS:
        for variant, c in (("stored", cal), ("stand-in", dataclasses.replace(cal, reference_shares=None))):
            method = f"{solver} {variant}"
            try:
                est, _ = comp_estimate(loaded, empty, None, draws["declared"], run_config, unfitted, kin_kw,
                                       solver, mount, cal=c)
            except PayloadAgentError as exc:
                rows.append(dict(base, method=method, error=str(exc)))
                continue
            rows.append(dict(cases._row(dict(base, method=method), est, mass, cog_mm, 0.0),
                             notes=[n for n in est.notes if "reference run" in n or "scatter" in n]))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default="realistic+asymmetry,realistic+ripple")
    p.add_argument("--pairs", default="j2_quarter:paper_bd,paper_bd:j2_quarter",
                   help="CALIBRATION:RUN procedure pairs, comma-separated")
    p.add_argument("--payloads", type=int, default=8)
    p.add_argument("--speed", type=float, default=10.0, help="sweep speed %% of both procedures (default 10)")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    pairs = [tuple(x.split(":")) for x in a.pairs.split(",")]
    jobs = [(s, c, r, a.speed, i, m, cog) for s in a.scenarios.split(",") for c, r in pairs
            for i, (m, cog) in enumerate(cases.payloads(a.payloads))]
    t0 = time.time()
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        rows = [r for rs in ex.map(run_case, jobs) for r in rs]
    print(f"{len(jobs)} cases, {time.time() - t0:.0f} s wall")
    for r in rows:
        if "error" in r:
            print(f"  failed: {r['scenario']} {r['procedure']} {r['method']} payload {r['payload']}: {r['error']}")
    if a.json:
        a.json.write_text(json.dumps({"cases": rows}, indent=1), encoding="utf-8")
    from benchmarks.calibration import cell

    print("| scenario | calibration>run | method | n | rms(err/σ) m / x / y / z | in 95 % m / c | mean |Δm| g |")
    keys = dict.fromkeys((r["scenario"], r["procedure"], r["method"]) for r in rows)
    for key in keys:
        sel = [r for r in rows if (r["scenario"], r["procedure"], r["method"]) == key and "error" not in r
               and r.get("z_mass") is not None]
        if sel:
            c = cell(sel)
            print(f"| {' | '.join(key)} | {c['n']} | {c['rms_m']:.2f} / {' / '.join(f'{v:.2f}' for v in c['rms_xyz'])}"
                  f" | {c['in95_m']:.2f} / {c['in95_c']:.2f} | {c['mean_abs_m_g']:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
