"""Power and false alarms of `payload-agent verify` on the simulated EC66 and UR5e (issue 23).

    python -m benchmarks.verify_power [--trials 120] [--robots sim-ec66,sim-ur5e] [--seeds 23,24,25]
        [--pooled-noise]

Per robot: the robot YAML's simulated arm (its friction, noise, effects) is driven in-process through
the identification plan with an empty flange (the stored baseline) and then, per trial, through the
verify motion that ``tools.verify_plan.choose`` picks, with the right tool or a wrong one mounted,
a fresh friction drift (±``DRIFT`` uniform, as between a baseline and a tool run) and fresh noise. The
physics and the samples are the simulated controller's own (``fakes.offline.record_plan``); only the
protocol is skipped, so thousands of verify motions take minutes. The statistics are exactly
``tools.verify_stats``. The library entry of the right tool is what a full run would store: the whole
identification plan recorded with the tool and fitted with the same model (``verify_stats.fit_theta``), so
it carries the method's own small biases as a real entry does (a truth-plus-noise entry does not, and
then a precise verify alarms on the method's bias, not on the tool).

Prints per robot: the chosen motion and its robot time, the predicted detection limits, the false-alarm
rate on the right tool (with its 95 % Clopper-Pearson upper bound), and the detection rate against mass
errors (same centre of mass) and centre-of-mass shifts along x, y and z (same mass).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import yaml
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
TOOL = (2.0, (40.0, -25.0, 70.0))
DRIFT = 0.05
MASS_ERRORS_PERCENT = (2.5, 5.0)
COG_ERRORS_MM = (5.0, 10.0, 12.5)


def _config(name: str):
    from payload_agent.configuration.config import parse_config

    return parse_config(yaml.safe_load((ROOT / "configs" / f"{name}.yaml").read_text()))


def _robot(config, seed: int):
    from payload_agent.fakes.arms import SPECS
    from payload_agent.fakes.base import sim_robot_kwargs
    from payload_agent.fakes.sim_robot import SimRobot

    kw = sim_robot_kwargs(config)
    kw["seed"] = seed
    tick = 0.008 if config.driver_type == "elite_ec" else 0.002
    return SimRobot(SPECS[config.simulation.arm](), tick_s=tick, **kw)


def _trial(robot, config, cand, baseline, sigma, theta0, S0, truth, rng) -> bool:
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.tools import verify_stats as vs

    robot.set_payload(PayloadTruth.point(truth[0], truth[1]))
    robot.set_friction_scale(1.0 + rng.uniform(-DRIFT, DRIFT))
    # every trial starts where the verify motion starts (the approach is the same each time)
    loaded, _ = record_plan(robot, cand.plan)
    windows = {(s.pose, s.joint): s.window for s in cand.segments}
    bins = vs.make_bins(windows, baseline, sigma, cand.segments[0].speed_rad_s, loaded)
    return vs.glrt(bins, config.robot.kinematics, theta0, S0).matches


def _library_entry(robot, config, baseline, sigma, m, c):
    """What `run --tool` would store: the whole identification plan with the tool, both directions, fitted
    (WLS on the same bins and regressor the verify uses), so the entry carries the method's own biases."""
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.motion.planner import make_plan
    from payload_agent.tools import verify_stats as vs

    plan = make_plan(config)
    robot.set_payload(PayloadTruth.point(m, c))
    loaded, _ = record_plan(robot, plan)
    windows = {}
    for i, mv in enumerate(plan.moves):
        if mv.sweep is not None and mv.sweep.direction == "up":
            j = mv.sweep.joint - 1
            windows[(mv.sweep.pose, mv.sweep.joint)] = vs.cruise_window(plan.moves[i - 1].target_rad[j],
                                                                         mv.target_rad[j], mv.speed_rad_s,
                                                                         mv.accel_rad_s2)
    bins = vs.make_bins(windows, baseline, sigma, plan.sweeps[0].speed_rad_s, loaded)
    return vs.fit_theta(bins, config.robot.kinematics)


def _upper95(k: int, n: int) -> float:
    return 1.0 if k == n else float(stats.beta.ppf(0.975, k + 1, n - k))


def run_robot(name: str, trials: int, seed: int = 23, h0_trials: int | None = None, h0_only: bool = False,
              apart: bool = True) -> dict[str, tuple[int, int]]:
    """Prints one robot state's rows (one seed: its baseline, library entry and verify motion) and returns them,
    label -> (detections, trials); the right tool's row counts false alarms."""
    from payload_agent.fakes.offline import record_plan
    from payload_agent.motion.planner import make_plan
    from payload_agent.tools import verify_plan, verify_stats as vs

    config = _config(name)
    rng = np.random.default_rng(seed)
    robot = _robot(config, seed)
    t0 = time.monotonic()
    baseline, _ = record_plan(robot, make_plan(config))
    sigma = vs.noise_std(baseline, apart=apart)
    m, c = TOOL
    theta0, S0 = _library_entry(robot, config, baseline, sigma, m, c)
    entry_m, entry_c = float(theta0[0]), tuple(1000 * theta0[1:] / theta0[0])
    entry = (f"library entry (a full loaded run of the plan, fitted with the same model): {entry_m:.4f} kg, "
             f"[{', '.join(f'{v:.2f}' for v in entry_c)}] mm, σ(m) {1000 * np.sqrt(S0[0, 0]):.1f} g")
    start_q = np.asarray(robot.snapshot().q_true, float)
    cand = verify_plan.choose(config, start_q, baseline, sigma, theta0, S0, 5.0, 10.0)
    print(f"\n== {name} ({config.simulation.arm}, {config.driver_type}), seed {seed}; baseline and choice in "
          f"{time.monotonic() - t0:.1f} s wall")
    print(entry)
    print(f"noise σ {sigma.describe()}" + ("" if apart else " (one σ per joint, pooled: --pooled-noise)"))
    print(f"motion: {cand.describe()}")
    print(f"robot time: {cand.motion_time_s:.2f} s from the verify start (every trial); {cand.robot_time_s:.2f} s from "
          "where the baseline ended (the approach at the approach speed included)")
    t0 = time.monotonic()
    n0 = h0_trials or trials
    alarms = sum(not _trial(robot, config, cand, baseline, sigma, theta0, S0, (m, c), rng) for _ in range(n0))
    print(f"right tool: {alarms}/{n0} false alarms ({100 * alarms / n0:.1f} %, 95 % upper bound "
          f"{100 * _upper95(alarms, n0):.1f} %)  [{time.monotonic() - t0:.0f} s wall]")
    rows = {"right tool (false alarms)": (alarms, n0)}
    if h0_only:
        return rows
    print(f"{'error':>22} | detected")
    for pct in MASS_ERRORS_PERCENT:
        hits = sum(not _trial(robot, config, cand, baseline, sigma, theta0, S0,
                              (m * (1 + rng.choice([-1, 1]) * pct / 100), c), rng) for _ in range(trials))
        print(f"{f'mass ±{pct:g} %':>22} | {hits}/{trials} = {100 * hits / trials:.1f} %")
        rows[f"mass ±{pct:g} %"] = (hits, trials)
    for d in COG_ERRORS_MM:
        for axis in range(3):
            shift = np.zeros(3)
            shift[axis] = d
            hits = sum(not _trial(robot, config, cand, baseline, sigma, theta0, S0,
                                  (m, tuple(np.asarray(c) + rng.choice([-1, 1]) * shift)), rng) for _ in range(trials))
            label = f"CoM {'xyz'[axis]} ±{d:g} mm"
            print(f"{label:>22} | {hits}/{trials} = {100 * hits / trials:.1f} %")
            rows[label] = (hits, trials)
    sys.stdout.flush()
    return rows


def print_pooled(name: str, per_seed: list[dict[str, tuple[int, int]]]) -> None:
    """The rows over every seed's robot state: a row's rate as a property of the test, not of one baseline draw
    (every trial of a seed shares its baseline and library entry, whose offsets move a row by ±20 points)."""
    print(f"\n== {name}: {len(per_seed)} seeds pooled")
    for label in per_seed[0]:
        k, n = sum(r[label][0] for r in per_seed), sum(r[label][1] for r in per_seed)
        each = " ".join(f"{100 * r[label][0] / r[label][1]:.0f}" for r in per_seed)
        print(f"{label:>26} | {k}/{n} = {100 * k / n:.1f} %  (per seed: {each} %)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=120)
    p.add_argument("--robots", default="sim-ec66,sim-ur5e")
    p.add_argument("--h0-trials", type=int, help="trials with the right tool (default --trials)")
    p.add_argument("--h0-only", action="store_true", help="only the false-alarm row")
    p.add_argument("--seeds", default="23", help="robot states (baseline, entry, noise), comma-separated; with "
                                                 "more than one the rows are also printed pooled")
    p.add_argument("--pooled-noise", action="store_true",
                   help="one noise σ per joint over all the baseline's sweeps (verify before session 22)")
    args = p.parse_args(argv)
    print(f"verify: α = 1 %, power target 95 %; {args.trials} trials per row; right tool {TOOL[0]} kg at "
          f"{list(TOOL[1])} mm; friction drift ±{100 * DRIFT:g} % per verify")
    seeds = [int(v) for v in args.seeds.split(",")]
    for name in args.robots.split(","):
        per_seed = [run_robot(name.strip(), args.trials, seed, h0_trials=args.h0_trials, h0_only=args.h0_only,
                              apart=not args.pooled_noise) for seed in seeds]
        if len(seeds) > 1:
            print_pooled(name.strip(), per_seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
