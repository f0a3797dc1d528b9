"""Where a reported σ comes from: a bi-cal-comp estimate's variance, part by part, against its error (issue 22).

Not a test: it prints one row per case of the accuracy benchmark (same robots, payloads, procedure,
calibration and declarations as ``benchmarks.accuracy``'s general-bi-cal-comp or three-step-bi-cal-comp) with
the actual error of one quantity (the mass, or one CoM axis) and its σ from each part of the reported
covariance: the autocorrelation-robust noise (and the independent-noise one beside it), each joint's
drive-gain uncertainty after the calibration, the DH lengths (less what the calibration absorbed; the
general solver only), the correlation of the shared empty baseline's noise between the calibration and the tool
run (a negative part, −√ of the variance it removes; each solver through its own map) and every systematic term of
``evaluation.systematics.TERMS`` through the solver's own sensitivities. The benchmark knows each effect's truth (``benchmarks.hard``; the realistic arm's draws in
``benchmarks.cases``), so a term that claims more than the arm has shows as a large column against a small
error, and an error no column covers points at an effect no term describes.

    .venv/bin/python -m benchmarks.sigma_budget [--scenarios realistic,hard] [--payloads 6] [--speed 10 |
        --procedure speed=10,travel=20,accel=20,sweep=0:55] [--solver general|three-step] [--quantity m|x|y|z]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import cases  # noqa: E402
from benchmarks.reference import calibration, theta_reference  # noqa: E402
from benchmarks.remedies import calibrated_gains, declaration, scaled  # noqa: E402


QUANTITIES = {"m": (0, 1000.0, "g"), "x": (1, 1000.0, "mm"), "y": (2, 1000.0, "mm"), "z": (3, 1000.0, "mm")}


def to_mass_cog(theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """A covariance of θ = [m, m·c] as one of [m, c_x, c_y, c_z] (first order: c = θ[1:]/m)."""
    m = float(theta[0])
    J = np.zeros((4, 4))
    J[0, 0] = 1.0
    J[1:, 0] = -np.asarray(theta[1:4]) / m ** 2
    J[1:, 1:] = np.eye(3) / m
    return J @ cov @ J.T


def analysed_case(scenario: str, index: int, proc: cases.Procedure, n_payloads: int) -> dict:
    """One case of the accuracy benchmark's general-bi-cal-comp, recorded and prepared as the analysis does
    (``analyse.prepared_run``: the calibration's zeros and per-angle gain errors corrected): the calibrated,
    compensated deltas (``prepared``), the fitted model, the calibration, the gains' uncertainty, the declaration the
    terms use, the payload (``mass``, ``cog`` mm), the arm's draws, where the loaded run started (``mount``), and the
    recorded sweeps (``loaded``, ``empty``, ``ref``) with the procedure's ``config``."""
    from payload_agent.evaluation.analyse import prepared_run
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.solvers import general

    mass, cog = cases.payloads(n_payloads)[index]
    draws = cases.robot_draws(scenario, index)
    plan_bi, _, config = cases.plans(proc)
    kin = config.robot.kinematics
    robot = cases._robot(draws, np.asarray(plan_bi.moves[0].target_rad),  # the accuracy benchmark's seed
                         int(round(proc.speed * 100)) + 7919 * int(round(proc.travel * 100 + proc.accel)))
    empty, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])
    robot.set_payload(PayloadTruth.point(mass, cog))
    mount = np.asarray(robot.snapshot().q, float)  # where the loaded run starts: the tool cable's rest
    robot.set_friction_scale(1.0 + draws["drift_load"])
    loaded, _ = record_plan(robot, plan_bi, torque_scale=draws["gain"])
    ref = cases.record_reference(robot, plan_bi, draws)
    decl = declaration(draws["declared"])
    cal = calibration(ref, empty, config, decl)  # what ``calibrate`` stores
    scale = np.asarray(cal.scale, float)
    gains = calibrated_gains(cal, cases.declared_unfitted_gain_std(scenario))
    gain_std = np.asarray(gains.rel_std, float)
    prepared, decl = prepared_run(scaled(loaded, scale), scaled(empty, scale), decl, gains, mount_rad=mount)
    model = general.fit_model(prepared.deltas, kin, gain_std)
    return dict(prepared=prepared, model=model, cal=cal, gain_std=gain_std, decl=decl, kin=kin, mass=mass, cog=cog,
                draws=draws, mount=mount, loaded=loaded, empty=empty, ref=ref, config=config)


def budget(scenario: str, index: int, proc: cases.Procedure, n_payloads: int, solver: str = "general",
           quantity: str = "m") -> dict[str, float]:
    """The error of one quantity (mass in g or a CoM axis in mm) and the σ of each part of the reported
    covariance, for one case (``solver``: "general" or "three-step", as general-bi-cal-comp and
    three-step-bi-cal-comp report it)."""
    from payload_agent.evaluation import shared_baseline, systematics
    from payload_agent.solvers import general, three_step, wls

    c = analysed_case(scenario, index, proc, n_payloads)
    prepared, model, cal, gain_std, decl, kin = c["prepared"], c["model"], c["cal"], c["gain_std"], c["decl"], c["kin"]
    mass, cog, fitted = c["mass"], c["cog"], c["cal"].fitted_joints
    res = model.fit()
    theta, groups = res.theta[:4], list(model.groups)
    parts: dict[str, np.ndarray] = {}
    key = systematics.ALL
    if solver == "general":
        noise_iid, noise = res.cov_iid[:4, :4], res.cov[:4, :4]
        Y = np.vstack([g.Y for g in groups])
        for j, s in enumerate(gain_std):
            one = np.where(np.arange(len(gain_std)) == j, s, 0.0)
            parts[f"gain j{j + 1}"] = wls.gain_covariance(groups, Y, res.weights, res.normal_inverse, theta, one)[:4, :4]
        length_std_m = cases.declared_length_std_mm(scenario) / 1000.0
        if length_std_m > 0:
            S = general.kinematic_sensitivities(list(model.sweeps), kin, groups, res.weights, res.normal_inverse,
                                                theta, (theta_reference(), fitted))
            parts["DH lengths"] = length_std_m ** 2 * (S.T @ S)  # S: (K, 4)
    else:
        key = systematics.THREE_STEP
        plain = three_step.solve(prepared.deltas, kin)
        with_gains = three_step.solve(prepared.deltas, kin, gain_rel_std=gain_std)
        theta = np.array([plain.mass_kg, *(plain.mass_kg * np.asarray(plain.cog_m))])
        noise = noise_iid = np.asarray(plain.covariance)
        parts["gains j2, j3"] = np.asarray(with_gains.covariance) - noise
    syst = systematics.evaluate(prepared, kin, decl, gain_std, model=model, gain_reference=cal.reference)
    for term in syst.terms:
        parts[term.name] = term.covariance(key)
    theta = theta - syst.shift(key)  # what the run reports: a declared cable's effect off θ̂ (``Term.shift``)
    i, unit, _ = QUANTITIES[quantity]
    truth = np.array([mass, *(np.asarray(cog) / 1000.0)])
    est = np.array([theta[0], *(np.asarray(theta[1:4]) / theta[0])])

    def std(cov):
        return unit * float(np.sqrt(max(to_mass_cog(theta, cov)[i, i], 0.0)))

    out = {"error": unit * float(est[i] - truth[i]), "noise (iid)": std(noise_iid), "noise": std(noise)}
    out.update({name: std(c) for name, c in parts.items() if std(c) > 0})
    total = noise + sum(parts.values(), np.zeros((4, 4)))
    # the benchmark's calibration subtracts the case's own empty run: counted once (either solver's own map)
    term = shared_baseline.cross_covariance if solver == "general" else shared_baseline.three_step_cross_covariance
    shared = term(model, cal.reference[0], cal.reference[1], gain_std)[:4, :4]
    if np.any(shared):
        # a negative part: printed as −√(what it takes away from the variance)
        out["shared baseline"] = -float(np.sqrt(max(std(total) ** 2 - std(total + shared) ** 2, 0.0)))
        total = total + shared
    out["total"] = std(total)
    return out


def main(argv: list[str] | None = None) -> int:
    from benchmarks.accuracy import add_procedure_arguments, speed_or_procedure

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="realistic,hard", help="comma-separated (benchmarks.cases.ALL_SCENARIOS)")
    p.add_argument("--payloads", type=int, default=6)
    add_procedure_arguments(p)
    p.add_argument("--solver", choices=("general", "three-step"), default="general")
    p.add_argument("--quantity", choices=tuple(QUANTITIES), default="m", help="mass (g) or one CoM axis (mm)")
    args = p.parse_args(argv)
    proc = speed_or_procedure(p, args.speed, args.procedure)
    for scenario in args.scenarios.split(","):
        if scenario not in cases.ALL_SCENARIOS:
            p.error(f"unknown scenario {scenario!r}; known: {', '.join(cases.ALL_SCENARIOS)}")
        rows = [budget(scenario, i, proc, args.payloads, args.solver, args.quantity) for i in range(args.payloads)]
        cols = list(dict.fromkeys(k for r in rows for k in r))
        unit = QUANTITIES[args.quantity][2]
        print(f"\n{scenario}, {proc.describe()}, {args.solver}: error and σ per part of {args.quantity}, {unit}")
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
