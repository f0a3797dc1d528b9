"""What the tool-cable (wrist) term does to σ on an arm with no wrist torque, over many noise draws (issue 22 item 3).

Not a test: it prints numbers. Seeded offline runs of a shipped simulated robot exactly as
``benchmarks.pose_agreement`` records them (a drive-gain calibration, then an empty and a loaded run of the
procedure under test, the product's ``evaluation.analyse``); the shipped sim-ec66 has no tool cable, so every seed
is one more noise draw of the same clean arm. Per seed the product's reported covariance is split into the wrist
term the run carries (the spring relaxed where the loaded run started, ``systematics.cable_spring``, as every
``run`` records the mount) and the rest; the free offsets' term (``systematics.wrist``, a run without the record)
is evaluated on the same data for comparison.

Printed per quantity (mass, CoM x, y, z): rms(err/σ) and 95 % coverage with σ as reported, without the wrist term,
and with the free offsets' term instead; the wrist term's share of the largest CoM σ (mean, and the spread of the
reported CoM σ over the seeds with and without it); and how often the run carries a chance term at all. "undeclared"
and "declared none" evaluate the wrist term as a robot YAML without ``robot.tool_cable_fitted`` and with it false
would (session 26), whatever the robot's YAML declares.

    .venv/bin/python -m benchmarks.wrist_null --robot sim-ec66 --seeds 60 --procedure j2_triple --speed 7 \\
        --travel 25 --accel 100 --sweep-deg 0:15 --calibrate-with 5:60,0,80 --calibrate-speed 5 [--json OUT]
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
from benchmarks.pose_agreement import add_run_arguments, record, seeded  # noqa: E402

Z95 = 1.959964
QUANTITIES = ("m", "x", "y", "z")
# "chance w·β̂β̂ᵀ": the spring's term as the run computes it where the test finds a cable (β̂β̂ᵀ + D), but below the
# test w·β̂β̂ᵀ only, without the share w·D of the effect's own uncertainty
# "undeclared" / "declared none": the run's wrist term as the robot YAML leaving ``robot.tool_cable_fitted`` out /
# declaring it false would make it (the rest of σ as reported)
VARIANTS = ("reported", "without wrist", "free offsets", "chance w·β̂β̂ᵀ", "undeclared", "declared none")


def sigmas(theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """σ of mass (g) and of each CoM axis (mm) of a covariance of θ = [m, m·c]."""
    from payload_agent.solvers.wls import cog_with_covariance

    _, cc = cog_with_covariance(theta, cov)
    return np.r_[1000.0 * np.sqrt(max(cov[0, 0], 0.0)), 1000.0 * np.sqrt(np.clip(np.diag(cc), 0.0, None))]


def one(config, cal_config, run_config, seed: int, reference: tuple) -> dict:
    """One seed: the error, and σ with the run's wrist term, without it, and with the free offsets' term instead."""
    from payload_agent.evaluation import systematics
    from payload_agent.evaluation.analyse import AnalysisOptions, analyse, prepared_run
    from payload_agent.solvers import general

    r = record(config, cal_config, run_config, seed, reference)
    options, gains = AnalysisOptions.from_config(run_config), r["gains"]
    result = analyse(r["loaded"], r["empty"], options, gains, commands=r["commands"], mount_rad=r["mount_rad"])
    est = result.primary
    # the wrist term as ``analyse`` evaluated it: the same prepared data and model, that term alone
    prepared, joints = prepared_run(r["loaded"], r["empty"], options.joints, gains, r["commands"], r["mount_rad"])
    model = general.fit_model(prepared.deltas, options.kin, gains.rel_std)

    def wrist_cov(p, decl=joints) -> tuple[np.ndarray, list[str]]:
        s = systematics.evaluate(p, options.kin, decl, gains.rel_std, terms=[systematics.wrist_terms], model=model,
                                 gain_reference=gains.reference)
        return s.covariance(), [t.note for t in s.terms]

    spring, notes = wrist_cov(prepared)
    undeclared, undeclared_notes = wrist_cov(prepared, dataclasses.replace(joints, tool_cable_fitted=None))
    none, none_notes = wrist_cov(prepared, dataclasses.replace(joints, tool_cable_fitted=False))
    test = spring_test(model, prepared, gains)
    chance = np.asarray(test.pop("chance_cov", np.zeros((4, 4))))
    free, _ = wrist_cov(dataclasses.replace(prepared, mount_rad=None))
    cov = np.asarray(est.covariance, float)[:4, :4]
    theta = est.mass_kg * np.r_[1.0, np.asarray(est.cog_m)]
    p = config.simulation.payload
    err = np.r_[1000.0 * (est.mass_kg - p.mass_kg), 1000.0 * np.asarray(est.cog_m) - np.asarray(p.cog_mm)]
    return {"seed": seed, "error": err.tolist(), "procedure_passed": bool(result.quality["passed"]),
            "std": {"reported": sigmas(theta, cov).tolist(), "without wrist": sigmas(theta, cov - spring).tolist(),
                    "free offsets": sigmas(theta, cov - spring + free).tolist(),
                    "chance w·β̂β̂ᵀ": sigmas(theta, cov - spring + chance).tolist(),
                    "undeclared": sigmas(theta, cov - spring + undeclared).tolist(),
                    "declared none": sigmas(theta, cov - spring + none).tolist()},
            "wrist_notes": notes, "notes_by_declaration": {"undeclared": undeclared_notes, "declared none": none_notes},
            "spring": test}


def spring_test(model, prepared, gains) -> dict:
    """The run's cable test on its data (``cable_spring.fit_spring`` as ``systematics.wrist_terms`` calls it): T, its
    null mean E₀[T] and 95 % quantile, and the weight of the term in σ."""
    from payload_agent.evaluation.systematics import cable_spring, offsets
    from payload_agent.solvers.fitted import ALL

    by_name = {d.key.name: d for d in model.sweeps}
    labels = sorted({offsets.wrist_joint(g, by_name[g.sweep]) for g in model.groups} - {None})
    s = cable_spring.fit_spring(model, labels, prepared.mount_rad, gain_reference=gains.reference) if labels else None
    if s is None:
        return {}
    res = model.fit(ALL)
    sens = offsets.offset_sensitivities(list(model.sweeps), model.groups_of(ALL), res.weights, res.normal_inverse,
                                        offsets.wrist_joint)
    AM = np.column_stack([sens.get(lab, np.zeros(4)) for lab in labels]) @ s.levers
    beta = AM @ s.stiffness_nm_per_rad
    D = AM @ s.cov @ AM.T
    chance = np.outer(beta, beta) + D if s.present else s.weight * np.outer(beta, beta)
    return {"T": s.statistic, "null_mean": s.null_mean, "critical": s.critical, "weight": s.weight,
            "joints": list(s.joints), "chance_cov": chance.tolist()}


def summary(runs: list[dict]) -> dict:
    err = np.array([r["error"] for r in runs])
    out = {}
    for v in VARIANTS:
        s = np.array([r["std"][v] for r in runs])
        z = err / s
        c = s[:, 1:].max(axis=1)
        out[v] = {"rms": np.sqrt(np.mean(z ** 2, axis=0)).tolist(), "in95": np.mean(np.abs(z) <= Z95, axis=0).tolist(),
                  "cog_max_mean_mm": float(c.mean()), "cog_max_spread": float(c.std(ddof=1) / c.mean()),
                  "cog_over_1mm": float(np.mean(c > 1.0)), "mass_mean_g": float(s[:, 0].mean())}
    out["with_term"] = float(np.mean([bool(r["wrist_notes"]) for r in runs]))
    for v in ("undeclared", "declared none"):
        out[f"with_term {v}"] = float(np.mean([bool(r["notes_by_declaration"][v]) for r in runs]))
    t = np.array([[r["spring"]["T"], r["spring"]["null_mean"]] for r in runs if r["spring"]])
    if len(t):
        out["T_mean"], out["T_null_mean"] = float(t[:, 0].mean()), float(t[:, 1].mean())
        out["found"] = float(np.mean([r["spring"]["T"] > r["spring"]["critical"] for r in runs if r["spring"]]))
    out["mean_error"] = err.mean(axis=0).tolist()
    out["sem_error"] = (err.std(axis=0, ddof=1) / np.sqrt(len(err))).tolist()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(ap, seeds=40)
    ap.add_argument("--json", metavar="OUT", help="write the per-seed rows and the summary here")
    args = ap.parse_args(argv)
    cand, reference, seeds = seeded(args, one)
    runs = []
    for seed, r in seeds:
        runs.append(r)
        s = r["std"]
        print(f"seed {seed:3d}: err " + " ".join(f"{v:+.2f}" for v in r["error"]) + " | σ reported "
              + " ".join(f"{v:.2f}" for v in s["reported"]) + " | without wrist "
              + " ".join(f"{v:.2f}" for v in s["without wrist"]) + ("  (wrist term)" if r["wrist_notes"] else ""),
              flush=True)
    out = summary(runs)
    print(f"\n{args.robot}, {cand.describe()}, calibrated with {reference[0]:g} kg at {reference[1]} mm: {len(runs)} "
          f"seeds, a wrist term in {out['with_term']:.2f} of them (undeclared {out['with_term undeclared']:.2f}, declared "
          f"none {out['with_term declared none']:.2f}); mean error "
          + " / ".join(f"{m:+.2f}±{e:.2f}" for m, e in zip(out["mean_error"], out["sem_error"])) + " (g, mm)")
    if "T_mean" in out:
        print(f"cable test: mean T {out['T_mean']:.2f} against its null mean {out['T_null_mean']:.2f} (as the run computes "
              f"it); found (T > 95 % quantile) in {out['found']:.2f}")
    print("| σ | rms(err/σ) m / x / y / z | in 95 % m / x / y / z | mean σ m g | largest CoM σ mm: mean, "
          "spread over seeds, share > 1 mm |\n|---|---|---|---|---|")
    for v in VARIANTS:
        o = out[v]
        print(f"| {v} | {' / '.join(f'{x:.2f}' for x in o['rms'])} | {' / '.join(f'{x:.2f}' for x in o['in95'])} | "
              f"{o['mass_mean_g']:.2f} | {o['cog_max_mean_mm']:.3f}, {100 * o['cog_max_spread']:.0f} %, "
              f"{o['cog_over_1mm']:.2f} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"procedure": cand.describe(), "summary": out, "runs": runs}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
