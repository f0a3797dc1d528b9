"""Which part of the run's σ is too wide when the run reuses the calibration's empty run? Offline, over seeds (issue 22).

Not a test: it prints numbers. Each seed is recorded offline as ``benchmarks.pose_agreement.record`` records it with
``shared_baseline`` (the calibration sweeps the procedure under test; the tool run subtracts the calibration's empty
run, as ``run`` does after ``calibrate`` on the same plan) and analysed three ways on the same sweeps:

- A, as the product does: the calibrated gains and zeros (its error e_A; the reported covariance split into its
  parts: the fit's noise, the gains, the DH lengths, the cross term of the shared baseline and each systematic term);
- B, at the simulation's exact gains and zeros (the simulated drives are the nominal ones): e_B is the tool run's own
  error (its loaded run's and the shared empty run's noise);
- C, the calibrated gains without the zeros: e_A − e_C is what the calibration's zeros did, e_C − e_B its gains.

Over the seeds, E[e_B²] is what the noise term claims, E[(e_A − e_B)²] what the gain and zero terms claim, and
2·E[e_B·(e_A − e_B)] what the cross term (``evaluation.shared_baseline``) claims; each line prints the measured beside
the claimed (mean over the seeds), per θ = [m, m·c] component, then rms(err/σ) with all parts and without the
declared DH-length and tool-cable terms (sim-ec66 simulates exact DH lengths and no cable unless told:
``--dh-error-mm`` draws each seed's lengths, uniform, as ``simulation.dh_length_error_mm`` does).

    .venv/bin/python -m benchmarks.baseline_split --seeds 30 --procedure j2_quarter --speed 3 --travel 25 \\
        --accel 100 --sweep-deg 0:70 --calibrate-with 5:60,0,80 [--dh-error-mm 0.866] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.pose_agreement import add_run_arguments, configs, record  # noqa: E402
from benchmarks.remedies import scaled  # noqa: E402
from benchmarks.seeded_runs import parse_reference  # noqa: E402

PARAMS = ("m", "m·cx", "m·cy", "m·cz")


def fit_parts(loaded, empty, options, gains, commands, mount_rad) -> tuple[np.ndarray, dict]:
    """θ = [m, m·c] of the general fit as ``analyse`` makes it, and its reported covariance part by part (4×4 each)."""
    from payload_agent.evaluation import shared_baseline, systematics, zero_offsets
    from payload_agent.solvers import general

    joints = zero_offsets.declaration(options.joints, gains.zeros)
    prepared = systematics.prepare(zero_offsets.corrected(loaded, gains.zeros),
                                   zero_offsets.corrected(empty, gains.zeros), joints, commands, mount_rad)
    model = general.fit_model(prepared.deltas, options.kin, gains.rel_std)
    syst = systematics.evaluate(prepared, options.kin, joints, gains.rel_std, model=model,
                                gain_reference=gains.reference)
    noise, with_gains = model.fit().cov, model.cov_params()
    est = general.estimate(model, length_std_m=options.length_std_m, gain_reference=gains.reference)
    parts = {"noise": noise, "gains": with_gains - noise, "lengths": np.asarray(est.covariance) - with_gains}
    for t in syst.terms:
        parts[t.name] = parts.get(t.name, 0.0) + t.covariance()
    if gains.shared_baseline and gains.reference is not None and gains.rel_std is not None:
        parts["shared baseline"] = shared_baseline.cross_covariance(model, gains.reference[0], gains.reference[1],
                                                                    gains.rel_std)
    return model.theta[:4], {k: np.asarray(v, float)[:4, :4] for k, v in parts.items()}


def one(config, run_config, seed: int, reference: tuple, dh_error_mm: float) -> dict:
    """One seed: e_A, e_B, e_C and A's covariance parts (module docstring)."""
    from payload_agent.evaluation.analyse import AnalysisOptions, Gains
    from payload_agent.fakes import arms

    exact = arms.SPECS[config.simulation.arm]
    if dh_error_mm > 0:  # this seed's arm, drawn as simulation.dh_length_error_mm draws it
        arms.SPECS[config.simulation.arm] = lambda: exact().with_dh_errors(
            np.random.default_rng((seed, arms.DH_ERROR_STREAM)), dh_error_mm / 1000.0)
    try:
        r = record(config, run_config, run_config, seed, reference, shared_baseline=True)
    finally:
        arms.SPECS[config.simulation.arm] = exact
    p, g, options = config.simulation.payload, r["gains"], AnalysisOptions.from_config(run_config)
    truth = np.r_[p.mass_kg, p.mass_kg * np.asarray(p.cog_mm) / 1000.0]
    scale = np.asarray(g.nm_per_unit) / np.asarray(config.effort.gains_nm_per_unit)
    rest = (r["commands"], r["mount_rad"])
    th_a, parts = fit_parts(r["loaded"], r["empty"], options, g, *rest)
    th_b, _ = fit_parts(scaled(r["loaded"], 1 / scale), scaled(r["empty"], 1 / scale), options,
                        Gains(g.nm_per_unit, "the simulation's"), *rest)
    th_c, _ = fit_parts(r["loaded"], r["empty"], options, dataclasses.replace(g, zeros=None, shared_baseline=False),
                        *rest)
    return {"seed": seed, "truth": truth.tolist(), "err_a": (th_a - truth).tolist(), "err_b": (th_b - truth).tolist(),
            "err_c": (th_c - truth).tolist(), "parts": {k: v.tolist() for k, v in parts.items()}}


def z_scores(rows: list[dict], leave_out: tuple = ()) -> np.ndarray:
    """err/σ of m, c_x, c_y, c_z per seed (the CoM's by the delta method), σ from the parts not in ``leave_out``."""
    out = []
    for r in rows:
        th, truth = np.asarray(r["truth"]) + np.asarray(r["err_a"]), np.asarray(r["truth"])
        cov = sum(np.asarray(v) for k, v in r["parts"].items() if k not in leave_out)
        J = np.zeros((3, 4))
        J[:, 0], J[:, 1:] = -th[1:] / th[0] ** 2, np.eye(3) / th[0]
        err = np.r_[th[0] - truth[0], th[1:] / th[0] - truth[1:] / truth[0]]
        out.append(err / np.sqrt(np.r_[cov[0, 0], np.diag(J @ cov @ J.T)]))
    return np.array(out)


def report(rows: list[dict]) -> None:
    a, b, c = (np.array([r[k] for r in rows]) for k in ("err_a", "err_b", "err_c"))
    names = sorted({k for r in rows for k in r["parts"]})
    claimed = {k: np.mean([np.asarray(r["parts"].get(k, np.zeros((4, 4)))) for r in rows], axis=0) for k in names}
    print(f"\n{len(rows)} seeds; variances in g² (m) and (g·m)² (m·c), measured over the seeds against claimed (mean)")
    print("| θ | E[e_A²] | claimed, all parts | E[e_B²] (tool run) | noise | E[(e_A−e_B)²] (calibration) | gains + zeros"
          " | 2E[e_B(e_A−e_B)] | shared baseline | DH lengths | others |\n|---|---|---|---|---|---|---|---|---|---|---|")
    for i, n in enumerate(PARAMS):
        d, cl = a[:, i] - b[:, i], {k: 1e6 * v[i, i] for k, v in claimed.items()}
        others = sum(v for k, v in cl.items() if k not in ("noise", "gains", "joint zeros", "shared baseline",
                                                           "lengths"))
        print(f"| {n} | {1e6 * np.mean(a[:, i] ** 2):.3f} | {sum(cl.values()):.3f} | {1e6 * np.mean(b[:, i] ** 2):.3f} | "
              f"{cl['noise']:.3f} | {1e6 * np.mean(d ** 2):.3f} | {cl['gains'] + cl.get('joint zeros', 0.0):.3f} | "
              f"{2e6 * np.mean(b[:, i] * d):+.3f} | {cl.get('shared baseline', 0.0):+.3f} | {cl['lengths']:.3f} | "
              f"{others:.3f} |")
    zero_part = a - c
    print("the calibration's part split (mass, g²): gains E[(e_C−e_B)²] %.3f, zeros E[(e_A−e_C)²] %.3f" % (
        1e6 * np.mean((c[:, 0] - b[:, 0]) ** 2), 1e6 * np.mean(zero_part[:, 0] ** 2)))
    for label, leave in (("all parts (reported)", ()), ("without the DH lengths", ("lengths",)),
                         ("without the DH lengths and the tool cable", ("lengths", "tool cable"))):
        z = z_scores(rows, leave)
        print(f"rms(err/σ) m / x / y / z {label}: " + " / ".join(f"{v:.2f}" for v in np.sqrt(np.mean(z ** 2, axis=0)))
              + "; in 95 %: " + " / ".join(f"{v:.2f}" for v in np.mean(np.abs(z) < 1.96, axis=0)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(ap, seeds=30)
    ap.add_argument("--dh-error-mm", type=float, default=0.0, help="each seed's DH lengths off by up to MM (uniform)")
    ap.add_argument("--json", metavar="OUT", help="write the per-seed rows here")
    args = ap.parse_args(argv)
    config, _, run_config, cand = configs(args.robot, args)
    reference = parse_reference(args.calibrate_with)
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rows.append(one(config, run_config, seed, reference, args.dh_error_mm))
        print(f"seed {seed:3d}: mass error {1000 * rows[-1]['err_a'][0]:+.3f} g (exact gains {1000 * rows[-1]['err_b'][0]:+.3f}"
              f" g)", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps({"procedure": cand.describe(), "runs": rows}))
    print(f"\n{args.robot}, {cand.describe()}, calibrated on it (shared empty run)")
    report(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
