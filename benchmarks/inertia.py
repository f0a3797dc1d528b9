"""Inertia from the wrist moves: error, 95 % coverage and refusals by tool, EC66 and UR5e (issue 21).

    python -m benchmarks.inertia [--quick] [--seeds N] [--robots ec66,ur5e] [--scenarios realistic,hard] [--one-joint]

Each case records the wrist moves of ``procedures/wrist_inertia.yaml`` (the plan of the sim YAML
with ``procedure.inertia: true``) on an in-process simulated arm (``fakes.offline``), once with the
empty flange and once with the tool (one arm: both runs share its gears' ripple phases and DH errors,
not their sensor noise), and runs the agent's own inertia analysis (``evaluation.wrist_inertia``). Scenarios:

- realistic, after calibration: the sim YAML's sensor noise (effort and angle), friction with a
  load-dependent part, DH lengths off by ±0.5 mm; drive gains exact (what ``calibrate`` buys);
- hard: the same plus every error source of ``benchmarks/hard.py`` (zero offsets, joint elasticity,
  gear ripple, friction asymmetry, warm-up, quantised effort, a weak tool cable).

m and m·c are given to the analysis as the static sweeps deliver them: the truth plus an error drawn
from a typical static σ (0.3 % of the mass, 1 mm of CoM per axis), with that covariance. The static
sweeps and their analysis are the same with and without the inertia part, so mass and CoM are
unchanged by it (the wrist moves come after the sweeps and enter only the inertia fit).

Columns: the largest element error of the tensor about the CoM relative to the largest principal
moment (cases not refused), the fraction of elements whose 95 % interval holds the truth, refusals,
and the extra robot time of the inertia part (planned durations: wrist moves + travel to them).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from benchmarks import hard

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = {"ec66": ("sim-ec66.yaml", 0.008), "ur5e": ("sim-ur5e.yaml", 0.002)}
SCENARIOS = ("realistic", "hard")
DH_ERROR_M = 0.0005
STATIC_MASS_REL_STD, STATIC_COG_STD_M = 0.003, 0.001


def box(m: float, a: float, b: float, c: float) -> np.ndarray:
    return m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


# name, mass kg, CoM mm, inertia about the CoM in the tool's own axes (rotated per case)
TOOLS = (
    ("flange plate 0.4 kg", 0.4, (0, 0, 10), box(0.4, 0.12, 0.12, 0.01)),
    ("compact gripper 1 kg", 1.0, (0, 0, 50), box(1.0, 0.08, 0.08, 0.10)),
    ("gripper 2 kg", 2.0, (40, -25, 70), np.array([[0.012, 0.001, -0.002], [0.001, 0.020, 0.003],
                                                   [-0.002, 0.003, 0.015]])),
    ("camera bracket 1.5 kg off-axis", 1.5, (80, 0, 40), box(1.5, 0.25, 0.06, 0.06)),
    ("long off-axis gripper 4.5 kg", 4.5, (50, -30, 150), box(4.5, 0.10, 0.15, 0.35)),
)


# The earlier wrist procedure (sessions 9-10): one wrist joint per move, 6, 5, 4, then 6 the other way, in the same
# two orientations; the shipped one turns joints 4, 5 and 6 together (docs/analysis.md, Inertia). ``--one-joint``.
ONE_JOINT_MOVES = [{"pose": p, "joint": j, "range_deg": r} for p in ("c", "b")
                   for j, r in ((6, [0, 60]), (5, [0, 45]), (4, [0, 45]), (6, [0, -40]))]


def one_joint_procedure() -> dict:
    """procedures/wrist_inertia.yaml with the earlier one-joint-at-a-time moves."""
    data = yaml.safe_load((ROOT / "procedures" / "wrist_inertia.yaml").read_text())
    return dict(data, name="wrist_one_joint", moves=ONE_JOINT_MOVES)


def config_for(robot: str, procedure: str | bool = True):
    """The sim YAML of ``robot`` with the inertia part on: the bundled procedure, or a wrist procedure file."""
    from payload_agent.configuration.config import parse_config

    data = yaml.safe_load((ROOT / "configs" / ROBOTS[robot][0]).read_text())
    data["procedure"]["inertia"] = procedure
    return parse_config(data, source=ROBOTS[robot][0])


def wrist_plan(cfg):
    """The inertia part of the YAML's plan (from the last sweep's end) and its extra robot time."""
    from payload_agent.motion.planner import Plan, expected_durations, make_plan

    plan = make_plan(cfg)
    last = plan.moves.index(plan.sweeps[-1])
    start = np.asarray(plan.moves[last].target_rad)
    part = plan.moves[last + 1:]
    durations = expected_durations(Plan(plan.procedure, part), np.asarray(start))
    return Plan(plan.procedure, part), np.asarray(start), float(np.nansum(durations))


def robot_for(cfg, robot: str, scenario: str, seed: int, payload, start):
    from payload_agent.fakes.arms import SPECS
    from payload_agent.fakes.base import sim_robot_kwargs
    from payload_agent.fakes.sim_robot import SimRobot

    rng = np.random.default_rng([seed, 21])
    spec = SPECS[cfg.simulation.arm]().with_dh_errors(rng, DH_ERROR_M)
    kw = sim_robot_kwargs(cfg)
    base = int(rng.integers(2**31))
    # the empty and the loaded run: one arm (its gears' ripple phases), two recordings (their noise)
    kw.update(payload=payload, q0_rad=start, seed=base + (1 if payload is not None else 0), ripple_seed=base)
    if scenario == "hard":
        tool_fx, _, _ = hard.draw(hard.HARD, seed)
        kw["effects"] = tool_fx
    return SimRobot(spec, tick_s=ROBOTS[robot][1], **kw)


def run_case(cfg, plan, start, robot, scenario, seed, tool, empty_cache):
    from payload_agent.evaluation.wrist_inertia import identify_inertia
    from payload_agent.fakes.offline import record_wrist_moves
    from payload_agent.fakes.physics import PayloadTruth

    name, mass, cog_mm, inertia_own = tool
    rng = np.random.default_rng([seed, 22, TOOLS.index(tool)])
    R = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    truth = R @ inertia_own @ R.T
    cog = np.asarray(cog_mm) / 1000.0
    key = (robot, scenario, seed)
    if key not in empty_cache:
        empty_cache[key] = record_wrist_moves(robot_for(cfg, robot, scenario, seed, None, start), plan)[0]
    r = robot_for(cfg, robot, scenario, seed, PayloadTruth.from_tensor(mass, cog, truth), start)
    loaded = record_wrist_moves(r, plan)[0]
    m_hat = mass * (1 + rng.normal(0, STATIC_MASS_REL_STD))
    c_hat = cog + rng.normal(0, STATIC_COG_STD_M, 3)
    theta = np.array([m_hat, *(m_hat * c_hat)])
    cov = np.diag([STATIC_MASS_REL_STD * mass, *(mass * STATIC_COG_STD_M,) * 3]) ** 2
    res = identify_inertia(loaded, empty_cache[key], cfg.robot.kinematics, theta, cov)
    largest = float(np.max(np.linalg.eigvalsh(truth)))
    err = res.estimate_kgm2 - truth
    iu = np.triu_indices(3)
    covered = np.abs(err[iu]) <= 1.96 * res.std_kgm2[iu]
    return {"robot": robot, "scenario": scenario, "tool": name, "largest_kgm2": largest,
            "err_rel": float(np.max(np.abs(err)) / largest), "covered": float(np.mean(covered)),
            "refused": res.refused is not None, "projected": res.inconsistent_data is not None}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one seed per case")
    ap.add_argument("--seeds", type=int, default=None, help="cases per robot, scenario and tool (default 4)")
    ap.add_argument("--robots", default="ec66,ur5e")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--one-joint", action="store_true", help="the earlier procedure: one wrist joint per move")
    args = ap.parse_args(argv)
    seeds = args.seeds or (1 if args.quick else 4)
    scenarios = [s for s in SCENARIOS if s in args.scenarios.split(",")]
    rows, times = [], {}
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        procedure: str | bool = True
        if args.one_joint:
            procedure = str(Path(tmp) / "wrist_one_joint.yaml")
            Path(procedure).write_text(yaml.safe_dump(one_joint_procedure()))
        for robot in args.robots.split(","):
            cfg = config_for(robot, procedure)
            plan, start, extra = wrist_plan(cfg)
            times[robot] = extra
            cache: dict = {}
            for scenario in scenarios:
                for seed in range(seeds):
                    for tool in TOOLS:
                        rows.append(run_case(cfg, plan, start, robot, scenario, seed, tool, cache))
    print(f"inertia benchmark{' (one wrist joint per move)' if args.one_joint else ''}: {seeds} case(s) per robot, "
          f"scenario and tool, {time.time() - t0:.0f} s of wall time")
    print("extra robot time of the inertia part (planned): " + ", ".join(f"{r} {t:.1f} s" for r, t in times.items()))
    head = f"{'robot':6} {'scenario':10} {'tool':32} {'λmax kg·m²':>11} {'err/λmax':>9} {'cover95':>8} {'refused':>8}"
    print(head)
    print("-" * len(head))
    for robot in dict.fromkeys(r["robot"] for r in rows):
        for scenario in scenarios:
            for tool in TOOLS:
                sel = [r for r in rows if r["robot"] == robot and r["scenario"] == scenario and r["tool"] == tool[0]]
                ok = [r for r in sel if not r["refused"]]
                err = f"{np.mean([r['err_rel'] for r in ok]):.3f}" if ok else "—"
                cover = f"{np.mean([r['covered'] for r in ok]):.2f}" if ok else "—"
                print(f"{robot:6} {scenario:10} {tool[0]:32} {sel[0]['largest_kgm2']:11.4f} {err:>9} {cover:>8} "
                      f"{sum(r['refused'] for r in sel):>4}/{len(sel)}")
            big = [r for r in rows if r["robot"] == robot and r["scenario"] == scenario and r["largest_kgm2"] >= 0.01
                   and not r["refused"]]
            if big:
                print(f"{robot:6} {scenario:10} {'tools with λmax >= 0.01 kg·m²':32} {'':11} "
                      f"{np.mean([r['err_rel'] for r in big]):9.3f} {np.mean([r['covered'] for r in big]):8.2f}")
    print("targets (issue 21, realistic): mean err/λmax <= 0.10 over tools with λmax >= 0.01 kg·m², coverage >= 0.90, "
          "extra robot time <= 20 s")


if __name__ == "__main__":
    main()
