"""How often does the quality gate's pose-agreement check refuse an honest run, and are its z values N(0, 1)?

Not a test: it prints numbers. Seeded offline runs (``fakes.offline.record_plan``, no sockets) of a shipped
simulated robot as ``benchmarks.seeded_runs --calibrate`` runs it: per seed, the simulation section's arm,
noise, friction and tool, a drive-gain calibration first (the YAML's procedure at ``--calibrate-speed`` with
the reference ``--calibrate-with``, through the product's ``calibration.fit_from_sweeps``), then an empty run
and a loaded run of the procedure under test, analysed by the product's own ``evaluation.analyse`` (the
calibrated gains, their σ, the DH lengths, the systematic terms: what ``run`` does) whose quality gate is
``quality.evaluate``. Nothing is wrong with these runs, so every refusal by the pose-agreement check is a
false one.

Printed per quantity (mass, CoM x, y, z) over every pair of poses of every run: the mean and standard deviation
of the signed z = (o_a − o_b) / σ_diff (N(0, 1) if σ_diff is right), rms z, the share of |z| above 2, 3 and the
limit; per run: the share refused by the pose-agreement check (any pair, any quantity) at the limits in effect
and at ``quality.pose_agreement_limits(--limits-of-pairs)``, each against the family-wise rate those limits claim
for N(0, 1) z's. ``--limits-of-pairs 1``: the two-pose limits, 3 σ / 3.5 σ, which every procedure used before the
number of pairs was counted; so one run gives the before and the after.

    .venv/bin/python -m benchmarks.pose_agreement --robot sim-ec66 --seeds 60 --procedure j2_triple \\
        --speed 10 --travel 25 --accel 100 --sweep-deg 0:20 --calibrate-with 5:60,0,80 --calibrate-speed 5
    .venv/bin/python -m benchmarks.pose_agreement --robot sim-ec66 --seeds 60 --procedure paper_bd \\
        --calibrate-with 5:60,0,80 --calibrate-speed 5        # the YAML's own procedure settings
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import yaml

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.remedies import scaled  # noqa: E402
from benchmarks.seeded_runs import parse_reference  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
QUANTITIES = ("mass", "cog x", "cog y", "cog z")


def configs(robot: str, args) -> tuple:
    """(the robot's config, the calibration's config, the config of the procedure under test); inertia off."""
    from payload_agent.configuration.config import parse_config
    from payload_agent.evaluation import design

    data = yaml.safe_load((ROOT / "configs" / f"{robot}.yaml").read_text())
    data.pop("watch", None)
    config = parse_config(data, source=f"configs/{robot}.yaml", base_dir=ROOT / "configs")
    pc = dataclasses.replace(config.procedure, inertia=None)
    config = dataclasses.replace(config, procedure=pc)
    cal = config if args.calibrate_speed is None else dataclasses.replace(
        config, procedure=dataclasses.replace(pc, speed_percent=args.calibrate_speed))
    lo, hi = (float(v) for v in args.sweep_deg.split(":")) if args.sweep_deg else (pc.sweep_from_deg, pc.sweep_to_deg)
    cand = design.Candidate(args.speed or pc.speed_percent, args.travel or pc.travel_speed_percent, lo, hi, 1,
                            args.accel or pc.accel_percent, args.procedure or pc.name)
    return config, cal, design.with_candidate(config, cand), cand


def record(config, cal_config, run_config, seed: int, reference: tuple, shared_baseline: bool = False) -> dict:
    """One seed recorded offline as ``seeded_runs --calibrate`` runs it: the drive-gain calibration, then an empty and a
    loaded run of ``run_config``'s procedure. {"loaded", "empty" (at the calibrated gains), "gains", "commands",
    "mount_rad", "config"}: what ``evaluation.analyse`` takes (also ``benchmarks.wrist_null``'s). ``shared_baseline``:
    the run records no empty run of its own and subtracts the calibration's, as ``run`` does after ``calibrate`` on
    the same plan (the stored baseline; ``Gains.shared_baseline``): ``cal_config`` and ``run_config`` plan alike."""
    from payload_agent.analysis.segmenter import sweep_commands
    from payload_agent.evaluation.analyse import Gains
    from payload_agent.evaluation.calibration import fit_from_sweeps
    from payload_agent.fakes.arms import SPECS
    from payload_agent.fakes.base import sim_robot_kwargs
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.fakes.sim_robot import SimRobot
    from payload_agent.motion.planner import make_plan

    sim = config.simulation
    cal_plan, plan = make_plan(cal_config), make_plan(run_config)
    kw = dict(sim_robot_kwargs(config), seed=seed, q0_rad=np.asarray(cal_plan.moves[0].target_rad))
    robot = SimRobot(SPECS[sim.arm](), tick_s=0.008 if config.driver_type == "elite_ec" else 0.002, **kw)

    def mount(truth, mounted: bool) -> None:  # the simulated cell's tool change (session.simulation.mount_tool)
        robot.set_payload(truth if mounted else None)
        robot.set_friction_scale(1.0 + (sim.friction_drift if mounted else 0.0))

    kg, cog_mm = reference
    cal_empty, _ = record_plan(robot, cal_plan)
    mount(PayloadTruth.point(kg, cog_mm), True)
    cal_loaded, _ = record_plan(robot, cal_plan)
    cal = fit_from_sweeps(cal_loaded, cal_empty, config, kg, np.asarray(cog_mm) / 1000.0,
                          commands=sweep_commands(cal_plan.moves))
    mount(None, False)
    if shared_baseline:
        if cal_plan.fingerprint() != plan.fingerprint():
            raise ValueError("a shared baseline needs the calibration's plan and the run's to be the same")
        empty = cal_empty
    else:
        empty, _ = record_plan(robot, plan)
    p = sim.payload
    mount(PayloadTruth.from_tensor(p.mass_kg, [c / 1000.0 for c in p.cog_mm], p.inertia_com_kgm2)
          if p.inertia_com_kgm2 is not None else PayloadTruth.point(p.mass_kg, p.cog_mm), True)
    mount_rad = np.asarray(robot.snapshot().q, float)  # where the loaded run starts, as the agent records it
    loaded, _ = record_plan(robot, plan)
    scale = np.asarray(cal.scale, float)  # the efforts at the calibrated gains, as the agent loads them
    gains = Gains(cal.gains_nm_per_unit, "calibration", rel_std=cal.gain_rel_std(), reference=cal.reference,
                  zeros=cal.zeros, shared_baseline=shared_baseline)
    return {"loaded": scaled(loaded, scale), "empty": scaled(empty, scale), "gains": gains,
            "commands": sweep_commands(plan.moves), "mount_rad": mount_rad, "config": run_config}


def one(config, cal_config, run_config, seed: int, reference: tuple) -> dict:
    """One seed: calibrate, record empty and loaded, analyse; the pose-agreement checks and the gate's verdict."""
    from payload_agent.evaluation.analyse import AnalysisOptions, analyse

    r = record(config, cal_config, run_config, seed, reference)
    result = analyse(r["loaded"], r["empty"], AnalysisOptions.from_config(run_config), r["gains"],
                     commands=r["commands"], mount_rad=r["mount_rad"])
    q = result.quality
    pose = [c for c in q["checks"] if " pose " in c["check"] and " vs " in c["check"]]
    others = [c["check"] for c in q["checks"] if not c["passed"] and c not in pose]
    return {"seed": seed, "pose_checks": pose, "other_failed": others, "passed": bool(q["passed"]),
            "poses": sorted(q["per_pose"])}


def _rate(z: float) -> float:
    """P(|Z| > z), Z ~ N(0, 1)."""
    return math.erfc(z / math.sqrt(2.0))


def correlated_rate(z_runs: np.ndarray, limits: np.ndarray, draws: int = 400_000) -> float:
    """P(any |z_i| > limit_i) for z ~ N(0, R), R the correlation matrix of the runs' z vectors (one row a run):
    what the check would refuse if every z were exactly N(0, 1) but correlated as measured (pairs share poses)."""
    if len(z_runs) < 3:
        return float("nan")
    corr = np.corrcoef(z_runs.T)
    z = np.random.default_rng(0).multivariate_normal(np.zeros(len(corr)), corr, draws, method="eigh")
    return float(np.mean(np.any(np.abs(z) > limits, axis=1)))


def quantity_of(check: dict) -> str:
    return next(n for n in QUANTITIES if check["check"].startswith(n))


def add_run_arguments(ap: argparse.ArgumentParser, seeds: int) -> None:
    """The options of the seeded runs ``record`` makes: robot, seeds, the procedure's overrides, the calibration."""
    ap.add_argument("--robot", default="sim-ec66")
    ap.add_argument("--seeds", type=int, default=seeds)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--procedure", help="procedure name (default: the YAML's)")
    ap.add_argument("--speed", type=float, help="sweep speed percent (default: the YAML's)")
    ap.add_argument("--travel", type=float, help="travel speed percent (default: the YAML's)")
    ap.add_argument("--accel", type=float, help="acceleration percent (default: the YAML's)")
    ap.add_argument("--sweep-deg", metavar="FROM:TO", help="sweep range (default: the YAML's)")
    ap.add_argument("--calibrate-with", metavar="KG:X,Y,Z", help="the calibration's reference (default 3:0,0,80)")
    ap.add_argument("--calibrate-speed", type=float, metavar="PERCENT", help="the calibration's sweep speed")


def seeded(args: argparse.Namespace, one_run):
    """(the candidate, the calibration's reference, an iterator of (seed, ``one_run``'s record)) for the options
    ``add_run_arguments`` defines."""
    config, cal_config, run_config, cand = configs(args.robot, args)
    reference = parse_reference(args.calibrate_with)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    return cand, reference, ((s, one_run(config, cal_config, run_config, s, reference)) for s in seeds)


def main(argv: list[str] | None = None) -> int:
    from payload_agent.evaluation import quality

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(ap, seeds=60)
    ap.add_argument("--limits-of-pairs", type=int, default=1,
                    help="also count refusals at the limits for this many pairs (1: the two-pose limits)")
    args = ap.parse_args(argv)
    cand, reference, seeds = seeded(args, one)
    runs = []
    for seed, r in seeds:
        runs.append(r)
        worst = max(r["pose_checks"], key=lambda c: c["value"] / c["limit"])
        print(f"seed {seed:3d}: largest {worst['check']} |z| {worst['value']:.2f} (limit {worst['limit']:.2f})"
              + ("" if all(c["passed"] for c in r["pose_checks"]) else "  REFUSED (pose agreement)")
              + (f"  other failed: {', '.join(r['other_failed'])}" if r["other_failed"] else "")
              + "  z " + " ".join(f"{c['z']:+.2f}" for c in r["pose_checks"]), flush=True)
    n_pairs = len(runs[0]["pose_checks"]) // len(QUANTITIES)
    print(f"\n{args.robot}, {cand.describe()}, calibrated with {reference[0]:g} kg at {reference[1]} mm"
          f"{'' if args.calibrate_speed is None else f' at {args.calibrate_speed:g} %'}: {len(runs)} honest runs, "
          f"poses {', '.join(runs[0]['poses'])} ({n_pairs} pair{'s' if n_pairs != 1 else ''})")
    print("| quantity | z values | mean z | std z | rms z | share |z| > 2 (N(0,1): 0.046) | > 3 (0.0027) | "
          "> limit | limit |\n|---|---|---|---|---|---|---|---|---|")
    for name in QUANTITIES:
        cs = [c for r in runs for c in r["pose_checks"] if quantity_of(c) == name]
        z = np.array([c["z"] for c in cs])
        a = np.abs(z)
        print(f"| {name} | {len(z)} | {z.mean():+.2f} | {z.std(ddof=1):.2f} | {np.sqrt(np.mean(z ** 2)):.2f} | "
              f"{np.mean(a > 2):.3f} | {np.mean(a > 3):.3f} | {np.mean([not c['passed'] for c in cs]):.3f} | "
              f"{cs[0]['limit']:.2f} |")
    def claimed(m_lim: float, c_lim: float) -> float:  # family-wise rate of the run's tests, z's N(0, 1), independent
        return 1.0 - ((1.0 - _rate(m_lim)) * (1.0 - _rate(c_lim)) ** 3) ** n_pairs

    first = runs[0]["pose_checks"]
    z_runs = np.array([[c["z"] for c in r["pose_checks"]] for r in runs])
    in_effect = (first[0]["limit"], first[1]["limit"])
    for label, (m_lim, c_lim) in (("the limits in effect", in_effect),
                                  (f"the limits for {args.limits_of_pairs} pair(s)",
                                   quality.pose_agreement_limits(args.limits_of_pairs))):
        out = [any(abs(c["z"]) > (m_lim if quantity_of(c) == "mass" else c_lim) for c in r["pose_checks"]) for r in runs]
        lim = np.array([m_lim if quantity_of(c) == "mass" else c_lim for c in first])
        print(f"runs refused by pose agreement at {label} (mass {m_lim:.2f} σ, CoM {c_lim:.2f} σ): {int(sum(out))} of "
              f"{len(runs)} ({np.mean(out):.3f}); claimed for N(0,1) z's: at most {claimed(m_lim, c_lim):.4f}; N(0,1) "
              f"z's with the runs' own correlation between the {len(first)} tests: {correlated_rate(z_runs, lim):.4f}")
    gate = np.mean([r["passed"] for r in runs])
    print(f"whole gate passed: {gate:.3f}; other checks that failed: "
          + (", ".join(sorted({c for r in runs for c in r["other_failed"]})) or "none"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
