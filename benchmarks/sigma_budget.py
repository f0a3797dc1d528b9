"""Where a reported mass σ comes from: the general-bi-cal-comp estimate's variance, term by term (issue 22).

Not a test: it prints one row per case of the accuracy benchmark (same robots, payloads, procedure,
calibration and declarations as ``benchmarks.accuracy``'s general-bi-cal-comp) with the actual mass error and
the mass σ of each part of the reported covariance: the autocorrelation-robust noise (and the
independent-noise one beside it), each joint's drive-gain uncertainty after the calibration, the DH lengths
(less what the calibration absorbed) and every systematic term of ``evaluation.systematics.TERMS``. The
benchmark knows each effect's truth (``benchmarks.hard``; the realistic arm's draws in ``benchmarks.cases``),
so a term that claims more than the arm has shows as a large column against a small error.

    .venv/bin/python -m benchmarks.sigma_budget [--scenarios realistic,hard] [--payloads 6] [--speed 10]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402
from benchmarks.reference import calibrate, theta_reference  # noqa: E402
from benchmarks.remedies import declaration, scaled  # noqa: E402


def budget(scenario: str, index: int, proc: cases.Procedure, n_payloads: int) -> dict[str, float]:
    """Mass error and the mass σ of each part of the reported covariance, in g, for one case."""
    from payload_agent.evaluation import systematics
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.solvers import general, wls

    mass, cog = cases.payloads(n_payloads)[index]
    draws = cases.robot_draws(scenario, index)
    plan_bi, _, config = cases.plans(proc)
    kin = config.robot.kinematics
    robot = cases._robot(draws, np.asarray(plan_bi.moves[0].target_rad),  # the accuracy benchmark's seed
                         int(round(proc.speed * 100)) + 7919 * int(round(proc.travel * 100 + proc.accel)))
    empty, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])
    robot.set_payload(PayloadTruth.point(mass, cog))
    robot.set_friction_scale(1.0 + draws["drift_load"])
    loaded, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])
    ref = cases.record_reference(robot, plan_bi, draws)
    decl = declaration(draws["declared"])
    scale, gain_std, fitted = calibrate(ref, empty, config, cases.declared_unfitted_gain_std(scenario), decl)
    prepared = systematics.prepare(scaled(loaded, scale), scaled(empty, scale), decl)
    model = general.fit_model(prepared.deltas, kin, gain_std)
    res = model.fit()
    theta, groups = res.theta, list(model.groups)
    out = {"error": 1000 * (theta[0] - mass), "noise (iid)": 1000 * np.sqrt(res.cov_iid[0, 0]),
           "noise": 1000 * np.sqrt(res.cov[0, 0])}
    Y = np.vstack([g.Y for g in groups])
    for j, s in enumerate(gain_std):
        one = np.where(np.arange(len(gain_std)) == j, s, 0.0)
        v = wls.gain_covariance(groups, Y, res.weights, res.normal_inverse, theta, one)[0, 0]
        if v > 0:
            out[f"gain j{j + 1}"] = 1000 * np.sqrt(v)
    length_std_m = cases.declared_length_std_mm(scenario) / 1000.0
    if length_std_m > 0:
        S = general.kinematic_sensitivities(list(model.sweeps), kin, groups, res.weights, res.normal_inverse,
                                            theta, (theta_reference(), fitted))
        out["DH lengths"] = 1000 * length_std_m * float(np.sqrt(np.sum(S[:, 0] ** 2)))
    for term in systematics.evaluate(prepared, kin, decl, gain_std, model=model).terms:
        out[term.name] = 1000 * float(np.sqrt(term.covariance()[0, 0]))
    parts = [v for k, v in out.items() if k not in ("error", "noise (iid)")]
    out["total"] = float(np.sqrt(np.sum(np.square(parts))))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="realistic,hard", help="comma-separated (benchmarks.cases.ALL_SCENARIOS)")
    p.add_argument("--payloads", type=int, default=6)
    p.add_argument("--speed", type=float, default=10.0, help="sweep speed, percent (travel 10 %%, accel 20 %%, 0–55°)")
    args = p.parse_args(argv)
    proc = cases.Procedure(f"{args.speed:g}", args.speed, cases.SPEED_ROW_TRAVEL, cases.SPEED_ROW_ACCEL,
                           *cases.SWEEP_DEG)
    for scenario in args.scenarios.split(","):
        if scenario not in cases.ALL_SCENARIOS:
            p.error(f"unknown scenario {scenario!r}; known: {', '.join(cases.ALL_SCENARIOS)}")
        rows = [budget(scenario, i, proc, args.payloads) for i in range(args.payloads)]
        cols = list(dict.fromkeys(k for r in rows for k in r))
        print(f"\n{scenario}, sweep {args.speed:g} %: mass error and mass σ per part, g")
        print("| case | " + " | ".join(cols) + " | err/σ |")
        print("|---" * (len(cols) + 2) + "|")
        for i, r in enumerate(rows):
            print(f"| {i} | " + " | ".join(f"{r[c]:.2f}" if c in r else "" for c in cols)
                  + f" | {r['error'] / r['total']:+.2f} |")
        z = np.array([r["error"] / r["total"] for r in rows])
        print(f"rms(err/σ) {np.sqrt(np.mean(z ** 2)):.2f}, in 95 % {np.mean(np.abs(z) <= 1.959964):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
