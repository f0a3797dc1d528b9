"""How often does the tool-cable check refuse a run of an arm that has no cable? (issue 22, sim-ur5e)

Not a test: it prints a table. Seeded offline runs (``fakes.offline.record_plan``, no sockets) of a
shipped simulated robot's arm, noise, friction and tool (its inertia tensor included), empty and loaded,
through the analysis' deltas (``systematics.prepare``) into ``evaluation.cable_check.check``. The check's
significance test claims a false-alarm rate of ``cable_check.ALPHA`` (χ² of the k wrist offsets against the
χ²_k quantile). Printed: the mean χ² against k, the share above the χ²_k 90 %, 99 % and 1 − ALPHA
quantiles, and the share of runs the check refused (significant and moving the result); and, since the
same deltas feed the estimate, the general fit's rms(err/σ) of mass and centre of mass with its own (noise)
covariance against the simulated tool. Then the tool-cable term's own presence test (``systematics.cable_spring``:
a spring relaxed where the loaded run started, its chi-bar-squared statistic T against the drawn 1 − ALPHA
quantile): the share of runs it finds a cable, the share whose σ gets a chance term ((T − E₀[T])⁺/T of the
effect), and that term's mass σ against the fit's own and against the free wrist offsets' term a run without
the record gets (``systematics.wrist``).

``--gap-rate`` drops samples as a busy host's simulated stream does (a gap of 10–29 samples starts after
any sample with this probability; 0.05 keeps about half), in the empty and the loaded run alike.

    .venv/bin/python -m benchmarks.cable_false_alarms --robot sim-ur5e --seeds 60 [--gap-rate 0.05]
        [--procedure j2_pair --speed 12 --sweep-deg 0:15] [--kernel-only]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]


def kept(n: int, rng: np.random.Generator, gap_rate: float) -> np.ndarray:
    """Which of n samples a stream with random gaps keeps (``gap_rate``: gap starts per kept sample, each gap
    10-29 samples long)."""
    keep = np.ones(n, bool)
    i = 0
    while i < n:
        if rng.random() < gap_rate:
            k = int(rng.integers(10, 30))
            keep[i:i + k] = False
            i += k
        else:
            i += 1
    return keep


def thin(sweeps: dict, rng: np.random.Generator, gap_rate: float) -> dict:
    """Each sweep without the samples of random gaps (``kept``)."""
    if gap_rate <= 0:
        return sweeps
    out = {}
    for key, sd in sweeps.items():
        keep = kept(len(sd.t), rng, gap_rate)
        out[key] = dataclasses.replace(sd, t=sd.t[keep], q=sd.q[keep], effort_nm=sd.effort_nm[keep])
    return out


def one(config, plan, seed: int, gap_rate: float, kernel_only: bool = False) -> dict:
    from payload_agent.evaluation import cable_check, systematics
    from payload_agent.solvers import general
    from payload_agent.fakes.arms import SPECS
    from payload_agent.fakes.base import sim_robot_kwargs
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.fakes.sim_robot import SimRobot

    sim = config.simulation
    kw = dict(sim_robot_kwargs(config), seed=seed, q0_rad=np.asarray(plan.moves[0].target_rad))
    robot = SimRobot(SPECS[sim.arm](), tick_s=0.008 if config.driver_type == "elite_ec" else 0.002, **kw)
    empty, _ = record_plan(robot, plan)
    p = sim.payload
    robot.set_payload(PayloadTruth.from_tensor(p.mass_kg, [c / 1000.0 for c in p.cog_mm], p.inertia_com_kgm2)
                      if p.inertia_com_kgm2 is not None else PayloadTruth.point(p.mass_kg, p.cog_mm))
    mount = np.asarray(robot.snapshot().q, float)  # where the loaded run starts, as the agent records it
    robot.set_friction_scale(1.0 + sim.friction_drift)  # as the simulated cell does on a tool change
    loaded, _ = record_plan(robot, plan)
    rng = np.random.default_rng(1000 + seed)
    prepared = systematics.prepare(thin(loaded, rng, gap_rate), thin(empty, rng, gap_rate), config.robot.joints,
                                   mount_rad=mount)
    deltas = prepared.deltas
    if kernel_only:  # the covariance before the noise maps: the residuals' Bartlett kernel alone
        deltas = {key: dataclasses.replace(d, noise_map=None) for key, d in deltas.items()}
    out = cable_check.check(deltas, config.robot.kinematics)
    est = general.solve(deltas, config.robot.kinematics)  # noise σ only: the fit's own covariance
    err = np.r_[est.mass_kg - p.mass_kg, np.asarray(est.cog_m) - np.asarray(p.cog_mm) / 1000.0]
    out["z"] = err / np.r_[est.mass_std_kg, est.cog_std_m]
    out["spring"] = spring_on(prepared, config.robot.kinematics)
    out["mass_std_g"] = 1000.0 * est.mass_std_kg
    return out


def spring_on(prepared, kin) -> dict:
    """The tool-cable term's test on a prepared run: T, its quantile, the weight and the term's mass σ (g)."""
    from payload_agent.evaluation import systematics
    from payload_agent.evaluation.systematics import cable_spring
    from payload_agent.solvers import general

    model = general.fit_model(prepared.deltas, kin)
    syst = systematics.evaluate(prepared, kin, systematics.RIGID, terms=[systematics.wrist_terms], model=model)
    labels = sorted({lab for lab in (offsets_label(g, model) for g in model.groups) if lab is not None})
    s = cable_spring.fit_spring(model, labels, prepared.mount_rad) if labels else None
    if s is None:
        return {}
    free = systematics.evaluate(dataclasses.replace(prepared, mount_rad=None), kin, systematics.RIGID,
                                terms=[systematics.wrist_terms], model=model)  # what a run without the record gets
    return {"T": s.statistic, "critical": s.critical, "present": s.present, "weight": s.weight,
            "term_mass_g": 1000.0 * float(np.sqrt(syst.covariance()[0, 0])),
            "free_term_mass_g": 1000.0 * float(np.sqrt(free.covariance()[0, 0]))}


def offsets_label(group, model):
    from payload_agent.evaluation.systematics import offsets

    sweep = next(d for d in model.sweeps if d.key.name == group.sweep)
    return offsets.wrist_joint(group, sweep)


def main(argv: list[str] | None = None) -> int:
    from payload_agent.configuration.config import parse_config
    from payload_agent.evaluation import cable_check, design
    from payload_agent.motion.planner import make_plan

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", default="sim-ur5e")
    ap.add_argument("--seeds", type=int, default=60)
    ap.add_argument("--gap-rate", type=float, default=0.0)
    ap.add_argument("--procedure", default="j2_pair")
    ap.add_argument("--speed", type=float, default=12.0)
    ap.add_argument("--sweep-deg", default="0:15")
    ap.add_argument("--kernel-only", action="store_true",
                    help="drop the deltas' noise maps (the covariance as before them, for comparison)")
    args = ap.parse_args(argv)
    config = parse_config(yaml.safe_load((ROOT / "configs" / f"{args.robot}.yaml").read_text()),
                          source=f"configs/{args.robot}.yaml", base_dir=ROOT / "configs")
    lo, hi = (float(v) for v in args.sweep_deg.split(":"))
    cand = design.Candidate(args.speed, 25.0, lo, hi, 1, 100.0, args.procedure)
    plan = make_plan(design.with_candidate(config, cand))
    chi2, refused, k, z, springs, std = [], 0, 0, [], [], []
    for seed in range(1, args.seeds + 1):
        c = one(config, plan, seed, args.gap_rate, args.kernel_only)
        if "chi2" not in c:
            print(f"seed {seed}: {c.get('note')}")
            continue
        chi2.append(c["chi2"])
        z.append(c["z"])
        springs.append(c["spring"])
        std.append(c["mass_std_g"])
        refused += not c["passed"]
        k = c["dof"]
        print(f"seed {seed:3d}: χ² {c['chi2']:6.1f} (k {k}, limit {c['chi2_limit']:.1f}), shift {c['mass_shift_g']:+7.1f} g "
              f"{c['cog_shift_mm']:6.1f} mm{'  REFUSED' if not c['passed'] else ''}"
              + (f"; cable T {c['spring']['T']:.1f} (limit {c['spring']['critical']:.1f}), term {c['spring']['term_mass_g']:.2f} g"
                 if c["spring"] else ""), flush=True)
    x = np.array(chi2)
    q = {p: cable_check.chi2_quantile(p, k) for p in (0.9, 0.99, 1.0 - cable_check.ALPHA)}
    print(f"\n{args.robot}, {cand.describe()}, gap rate {args.gap_rate:g}{', kernel only' if args.kernel_only else ''}, {len(x)} runs without a cable: mean χ² "
          f"{x.mean():.2f} (k = {k}); above the χ²_k 90 % quantile {np.mean(x > q[0.9]):.3f}, 99 % "
          f"{np.mean(x > q[0.99]):.3f}, {1 - cable_check.ALPHA:g} {np.mean(x > q[1.0 - cable_check.ALPHA]):.3f} "
          f"(claimed {cable_check.ALPHA:g}); refused {refused} of {len(x)}")
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    print(f"the general fit's own σ (noise only) against its error, rms(err/σ) m / cx / cy / cz: "
          f"{' / '.join(f'{v:.2f}' for v in rms)}")
    sp = [s for s in springs if s]
    if sp:
        found = np.mean([s["present"] for s in sp])
        chance = np.mean([s["weight"] > 0 for s in sp])
        term = np.array([s["term_mass_g"] for s in sp])
        free = np.array([s["free_term_mass_g"] for s in sp])
        print(f"tool-cable term (spring relaxed where the loaded run started), {len(sp)} runs: found (T > its 95 % "
              f"quantile) in {found:.3f}; a chance term in {chance:.3f}; its mass σ mean {term.mean():.2f} g, "
              f"rms {np.sqrt(np.mean(term ** 2)):.2f} g (the fit's own mass σ {np.mean(std):.2f} g); the free wrist "
              f"offsets' term (runs without the record) in {np.mean(free > 0):.3f}, mass σ rms "
              f"{np.sqrt(np.mean(free ** 2)):.2f} g")
    return 0


if __name__ == "__main__":
    sys.exit(main())
