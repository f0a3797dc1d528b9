"""Accuracy benchmark: simulated EC66, seeded payloads, three methods, two scenarios, four speeds.

Not a test. Run ``.venv/bin/python -m benchmarks.accuracy [--quick] [--json PATH]``.

For speed the simulated robot is driven directly (no sockets, no clock thread): the
planner's moves go to ``SimRobot.move_joints`` and ``SimRobot.step()`` is called until
each move ends; the states of every sweep become ``SweepData`` exactly as the recorder's
CSV would after unit conversion. Then the agent's own pipeline runs:
``delta.subtract_all`` -> ``combine.add_combined`` -> solvers.

Each case simulates the bidirectional plan once (empty and loaded run). The unidirectional
methods use only its "up" sweeps, which are sampled exactly as the unidirectional plan
would sample them (each up sweep starts from standstill at the same start pose); the
motion time reported for them is the unidirectional plan's.

Scenarios
  ideal      sensor noise 0.3 N·m, constant Coulomb + viscous friction, exact gains and DH.
  realistic  ideal + load-dependent Coulomb (5 % of the load torque), friction scale drift
             ±10 % between the empty and the loaded run, drive gains off by up to ±3 % per
             joint (the measured torque is multiplied), the simulated arm's DH lengths off by
             up to 0.5 mm (ArmSpec.with_dh_errors) while the agent uses the nominal ones.
Methods
  three-step   the paper's solver, "up" sweeps only
  general-up   weighted least squares, "up" sweeps only
  general-bi   weighted least squares on up/down sweeps combined at matching angles
Ablation (``--scenarios realistic-exact-gains``): realistic with exact drive gains.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "sim-ec66.yaml"
SPEEDS = (1.0, 5.0, 10.0, 20.0)
SCENARIOS = ("ideal", "realistic")
# ablation, only with --scenarios: realistic but with exact drive gains (what `calibrate` would buy)
ALL_SCENARIOS = (*SCENARIOS, "realistic-exact-gains")
METHODS = ("three-step", "general-up", "general-bi")
NOISE_NM = 0.3
COULOMB_NM = (4.0, 4.0, 3.0, 1.0, 1.0, 0.5)
VISCOUS_NM_S_RAD = (8.0, 8.0, 5.0, 1.0, 1.0, 0.5)
TICK_S = 0.008  # the Elite monitor's sample period


def payloads(n: int, seed: int = 2025) -> list[tuple[float, tuple[float, float, float]]]:
    """n seeded payloads: 0.5–5 kg, centre of mass anywhere within 150 mm of the flange centre."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        m = float(rng.uniform(0.5, 5.0))
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        r = float(rng.uniform(0.0, 150.0))
        if d[2] < 0:  # tools stick out of the flange: keep z positive
            d[2] = -d[2]
        out.append((m, tuple(float(v) for v in d * r)))
    return out


def _config(speed_percent: float, bidirectional: bool):
    from payload_agent.config import load_config

    config = load_config(CONFIG)
    proc = dataclasses.replace(config.procedure, speed_percent=speed_percent, bidirectional=bidirectional)
    return dataclasses.replace(config, procedure=proc)


def run_phase(robot, plan, gain: np.ndarray) -> dict:
    """Drive every move of the plan; return SweepData per sweep (effort already in N·m)."""
    from payload_agent.rundata import SweepData

    out = {}
    for move in plan.moves:
        robot.move_joints(move.target_rad, move.speed_rad_s, move.accel_rad_s2)
        rec = [] if move.sweep is not None else None
        while True:
            s = robot.step()
            if rec is not None:
                rec.append((s.t, s.q, s.torque_nm))
            if not s.moving:
                break
        if rec is not None:
            for _ in range(5):  # the stream keeps going briefly after the move, as on the robot
                s = robot.step()
                rec.append((s.t, s.q, s.torque_nm))
            t = np.array([r[0] for r in rec])
            q = np.array([r[1] for r in rec])
            tau = np.array([r[2] for r in rec]) * gain
            out[move.sweep] = SweepData(move.sweep, t, q, tau, f"sim:{move.sweep.name}")
    return out


def motion_time_s(plan) -> float:
    """Robot time of one run without the approach move (which depends on where the robot stands)."""
    from payload_agent.planner import move_duration_s

    total, prev = 0.0, None
    for m in plan.moves:
        tgt = np.asarray(m.target_rad)
        if prev is not None:
            total += move_duration_s(prev, tgt, m.speed_rad_s, m.accel_rad_s2)
        prev = tgt
    return total


def run_case(args: tuple) -> list[dict]:
    scenario, speed, index, mass, cog_mm = args
    from payload_agent.combine import add_combined
    from payload_agent.delta import subtract_all
    from payload_agent.errors import DataError
    from payload_agent.fakes.arms import SPECS
    from payload_agent.fakes.physics import FrictionParams, PayloadTruth
    from payload_agent.fakes.sim_robot import SimRobot
    from payload_agent.planner import make_plan
    from payload_agent.solvers import general, three_step

    # the ablation draws the same DH errors, gains (then discarded) and drift as "realistic"
    seed_scenario = SCENARIOS.index("realistic" if scenario.startswith("realistic") else scenario)
    rng = np.random.default_rng([index, int(speed * 10), seed_scenario])
    config_bi = _config(speed, True)
    plan_bi, plan_up = make_plan(config_bi), make_plan(_config(speed, False))
    kin = config_bi.robot.kinematics
    spec = SPECS["ec66"]()
    realistic = scenario.startswith("realistic")
    if realistic:
        spec = spec.with_dh_errors(rng, 0.0005)
        gain = rng.uniform(0.97, 1.03, 6)
        if scenario == "realistic-exact-gains":
            gain = np.ones(6)
        drift = float(rng.uniform(-0.10, 0.10))
        load_ratio = 0.05
    else:
        gain, drift, load_ratio = np.ones(6), 0.0, 0.0
    friction = FrictionParams(np.array(COULOMB_NM), np.array(VISCOUS_NM_S_RAD), np.full(6, load_ratio))
    start = np.asarray(plan_bi.moves[0].target_rad)
    robot = SimRobot(spec, q0_rad=start, tick_s=TICK_S, friction=friction, noise_nm=NOISE_NM,
                     seed=int(rng.integers(2**31)), payload=None)
    empty = run_phase(robot, plan_bi, gain)
    robot.set_payload(PayloadTruth.point(mass, cog_mm))
    robot.set_friction_scale(1.0 + drift)
    loaded = run_phase(robot, plan_bi, gain)

    deltas = subtract_all(loaded, empty)
    up_only = {k: d for k, d in deltas.items() if k.direction == "up"}
    combined, _ = add_combined(deltas)
    truth_c = np.asarray(cog_mm) / 1000.0
    rows = []
    for method in METHODS:
        try:
            if method == "three-step":
                est, plan = three_step.solve(up_only, kin), plan_up
            elif method == "general-up":
                est, plan = general.solve(up_only, kin), plan_up
            else:
                est, plan = general.solve(combined, kin), plan_bi
        except DataError as exc:
            rows.append({"scenario": scenario, "speed_percent": speed, "method": method, "payload": index,
                         "error": str(exc)})
            continue
        dm = est.mass_kg - mass
        dc = np.asarray(est.cog_m) - truth_c
        rows.append({
            "scenario": scenario, "speed_percent": speed, "method": method, "payload": index,
            "mass_kg": mass, "cog_mm": list(cog_mm),
            "est_mass_kg": est.mass_kg, "est_cog_mm": list(est.cog_mm),
            "mass_err_g": 1000 * dm, "cog_err_mm": float(1000 * np.linalg.norm(dc)),
            "mass_std_g": None if est.mass_std_kg is None else 1000 * est.mass_std_kg,
            "cog_std_mm": None if est.cog_std_m is None else [1000 * v for v in est.cog_std_m],
            "z_mass": None if est.mass_std_kg is None else dm / est.mass_std_kg,
            "z_cog": None if est.cog_std_m is None else (dc / np.asarray(est.cog_std_m)).tolist(),
            "motion_time_s": motion_time_s(plan),
        })
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    out = []
    keys = sorted({(r["scenario"], r["speed_percent"], r["method"]) for r in rows},
                  key=lambda k: (ALL_SCENARIOS.index(k[0]), k[1], METHODS.index(k[2])))
    for sc, sp, me in keys:
        rs = [r for r in rows if (r["scenario"], r["speed_percent"], r["method"]) == (sc, sp, me)]
        ok = [r for r in rs if "error" not in r]
        s = {"scenario": sc, "speed_percent": sp, "method": me, "cases": len(rs), "failed": len(rs) - len(ok)}
        if ok:
            dm = np.abs([r["mass_err_g"] for r in ok])
            dc = np.array([r["cog_err_mm"] for r in ok])
            s.update(mass_err_mean_g=float(dm.mean()), mass_err_max_g=float(dm.max()),
                     cog_err_mean_mm=float(dc.mean()), cog_err_max_mm=float(dc.max()),
                     motion_time_s=float(np.mean([r["motion_time_s"] for r in ok])))
            zm = [r["z_mass"] for r in ok if r["z_mass"] is not None]
            zc = [v for r in ok if r["z_cog"] is not None for v in r["z_cog"]]
            s["z_rms_mass"] = float(np.sqrt(np.mean(np.square(zm)))) if zm else None
            s["z_rms_cog"] = float(np.sqrt(np.mean(np.square(zc)))) if zc else None
        out.append(s)
    return out


def format_table(summary: list[dict]) -> str:
    head = ["scenario", "speed %", "method", "Δm mean g", "Δm max g", "Δc mean mm", "Δc max mm",
            "motion s", "rms(err/σ) m", "rms(err/σ) c", "failed"]
    lines = []
    for s in summary:
        def f(key, fmt="{:.1f}"):
            v = s.get(key)
            return "-" if v is None else fmt.format(v)
        lines.append([s["scenario"], f"{s['speed_percent']:g}", s["method"], f("mass_err_mean_g"),
                      f("mass_err_max_g"), f("cog_err_mean_mm", "{:.2f}"), f("cog_err_max_mm", "{:.2f}"),
                      f("motion_time_s", "{:.0f}"), f("z_rms_mass", "{:.2f}"), f("z_rms_cog", "{:.2f}"),
                      f"{s['failed']}/{s['cases']}"])
    widths = [max(len(r[i]) for r in [head, *lines]) for i in range(len(head))]
    text = ["| " + " | ".join(h.ljust(w) for h, w in zip(head, widths)) + " |",
            "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    text += ["| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |" for r in lines]
    return "\n".join(text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="3 payloads at 5 %% speed (< 2 min)")
    p.add_argument("--payloads", type=int, default=10, help="number of seeded payloads (full run)")
    p.add_argument("--speeds", help="comma-separated speed percentages (default 1,5,10,20; quick: 5)")
    p.add_argument("--scenarios", help=f"comma-separated, from {', '.join(ALL_SCENARIOS)} (default: "
                   f"{', '.join(SCENARIOS)})")
    p.add_argument("--jobs", type=int, default=0, help="worker processes (default: all CPUs)")
    p.add_argument("--json", help="write every case and the summary to this path")
    args = p.parse_args(argv)
    n = 3 if args.quick else args.payloads
    speeds = tuple(float(v) for v in args.speeds.split(",")) if args.speeds else ((5.0,) if args.quick else SPEEDS)
    scenarios = tuple(args.scenarios.split(",")) if args.scenarios else SCENARIOS
    unknown = [sc for sc in scenarios if sc not in ALL_SCENARIOS]
    if unknown:
        p.error(f"unknown scenario(s) {', '.join(unknown)}")
    cases = [(sc, sp, i, m, c) for sc in scenarios for sp in speeds for i, (m, c) in enumerate(payloads(n))]
    t0 = time.monotonic()
    rows: list[dict] = []
    jobs = args.jobs or None
    # slow speeds take longest: start them first
    cases.sort(key=lambda c: c[1])
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for r in pool.map(run_case, cases):
            rows.extend(r)
    summary = summarize(rows)
    elapsed = time.monotonic() - t0
    print(f"payload-agent accuracy benchmark: EC66 simulator, {n} payloads, speeds {', '.join(f'{s:g}' for s in speeds)} % "
          f"of 144 deg/s, {len(cases)} simulated empty+loaded pairs, {elapsed:.0f} s")
    print(format_table(summary))
    for r in rows:
        if "error" in r:
            print(f"  failed: {r['scenario']} {r['speed_percent']:g} % {r['method']} payload {r['payload']}: {r['error']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "cases": rows, "elapsed_s": elapsed,
                                               "quick": args.quick}, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    if __package__ in (None, ""):
        sys.path.insert(0, str(ROOT))
    sys.exit(main())
