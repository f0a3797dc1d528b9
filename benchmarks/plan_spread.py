"""Does the plan's spread of the reported mass σ match the runs'? Offline seeded runs, plan beside run (issue 22 item 3).

Not a test: it prints numbers. Each seed is recorded offline as ``benchmarks.pose_agreement`` records it (a drive-gain
calibration, then an empty and a loaded run of the procedure under test, the simulation's own noise) and analysed by
the product's ``evaluation.analyse``. The plan's prediction for the same seed is made as ``plan --target-std`` makes
it after that calibration (its gains' and zeros' uncertainty, the calibration run's noise inflation and the
declared effort noise of the simulation section), and the run's reported mass σ is set against the plan's draws:

- rep/pred: the reported σ over the plan's median (its mean and its relative spread over the seeds);
- z = ln(rep/pred) / the relative spread of the plan's draws: a plan whose draws are as wide as the runs scatter gives
  rms(z) ≈ 1; above 1 the plan's risk ("P over") is too small;
- the plan's mean chance of a mass σ over ``--target-g`` against the share of runs over it.

``--before``: the plan's inflation as it was until session 18 (the calibration run's robust-to-white ratio over the
fixed ``noise_inflation.WHITE_RATIO``, its estimate error not drawn), on the same recordings.

``--shared-baseline``: the calibration sweeps the procedure under test (its speed, range and accelerations) and the run
subtracts the calibration's empty run instead of recording its own, as ``run`` does after ``calibrate`` on the same
plan (the stored baseline); the run's σ then carries the correlation of the two (``evaluation.shared_baseline``), and
so does the plan's (``planned_baseline``). Each row also gives the plan without that term (``planned_g_without``,
as it predicted before session 19). ``--calibrate-speed`` is ignored then.

    .venv/bin/python -m benchmarks.plan_spread --seeds 60 --procedure j2_triple --speed 7 --travel 25 --accel 100 \\
        --sweep-deg 0:15 --calibrate-with 5:60,0,80 --calibrate-speed 5 [--before] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.pose_agreement import add_run_arguments, configs, record  # noqa: E402
from benchmarks.seeded_runs import parse_reference  # noqa: E402


def recorded_with_calibration(config, cal_config, run_config, seed: int, reference: tuple,
                              shared_baseline: bool = False) -> tuple[dict, tuple]:
    """``pose_agreement.record``'s recording and the calibration's own sweeps (loaded, empty, commands), which the
    plan measures its inflation in (``calibrate`` keeps them in its run folder)."""
    from payload_agent.evaluation import calibration

    kept = {}
    fit = calibration.fit_from_sweeps

    def keep(loaded, empty, cfg, *args, **kwargs):
        kept["sweeps"] = (loaded, empty, kwargs.get("commands"))
        return fit(loaded, empty, cfg, *args, **kwargs)

    calibration.fit_from_sweeps = keep
    try:
        r = record(config, cal_config, run_config, seed, reference, shared_baseline)
    finally:
        calibration.fit_from_sweeps = fit
    return r, kept["sweeps"]


def planned(config, cand, r: dict, cal_sweeps: tuple, before: bool, shared_baseline: bool = False):
    """The plan's prediction (``design.predict``) for this seed's calibration, as ``session.target.noise_for`` forms
    its noise model from a stored calibration and the simulation section (``shared_baseline``: the stored baseline is
    the calibration's empty run, of the candidate's plan)."""
    from payload_agent.evaluation import design, noise_inflation
    from payload_agent.evaluation.zero_offsets import declaration

    sim, gains = config.simulation, r["gains"]
    m = noise_inflation.measure(config, *cal_sweeps)
    if before:
        inflation, rel_std = max(1.0, max(m.mass_ratio, m.cog_ratio) / noise_inflation.WHITE_RATIO), 0.0
    else:
        inflation, rel_std = m.excess, m.rel_std
    joints = config.robot.joints if gains.zeros is None else declaration(config.robot.joints, gains.zeros)
    noise = design.NoiseModel(tuple(sim.noise_nm), 0.008 if config.driver_type == "elite_ec" else 0.002,
                              inflation=inflation, inflation_rel_std=rel_std, gain_rel_std=gains.rel_std,
                              gain_reference=gains.reference, length_std_m=config.robot.length_uncertainty_m,
                              joints=joints, friction_level_nm=tuple(sim.coulomb_nm),
                              effort_rest_std_nm=None if sim.noise_rest_nm is None else tuple(sim.noise_rest_nm))
    if shared_baseline:
        from payload_agent.evaluation.planned_baseline import SharedBaseline
        from payload_agent.motion.planner import make_plan

        noise = dataclasses.replace(noise, shared_baseline=SharedBaseline(
            make_plan(design.with_candidate(config, cand)).fingerprint(), cand.procedure or config.procedure.name,
            cand.speed_percent))
    theta = design.nominal_theta(sim.payload.mass_kg, sim.payload.cog_mm)
    return design.predict(config, cand, noise, theta, check_safety=False), inflation


def one(config, cal_config, run_config, cand, seed: int, reference: tuple, before: bool, target_g: float,
        shared_baseline: bool = False) -> dict:
    from payload_agent.evaluation.analyse import AnalysisOptions, analyse

    r, cal_sweeps = recorded_with_calibration(config, cal_config, run_config, seed, reference, shared_baseline)
    est = analyse(r["loaded"], r["empty"], AnalysisOptions.from_config(run_config), r["gains"], commands=r["commands"],
                  mount_rad=r["mount_rad"]).primary
    p, inflation = planned(config, cand, r, cal_sweeps, before, shared_baseline)
    draws = p.draws[:, 0]
    row = {"seed": seed, "reported_g": 1000.0 * est.mass_std_kg, "planned_g": p.mass_std_g, "inflation": inflation,
           "draw_spread": float(np.std(np.log(draws / p.mass_std_g))), "p_over_mass": float(np.mean(draws > target_g)),
           "error_g": 1000.0 * (est.mass_kg - config.simulation.payload.mass_kg),
           "reported_cog_mm": 1000.0 * float(np.max(est.cog_std_m)), "planned_cog_mm": p.cog_std_mm,
           "cog_error_mm": [float(v) for v in np.asarray(est.cog_mm) - np.asarray(config.simulation.payload.cog_mm)]}
    if shared_baseline:  # the plan as it was before session 19, without the term
        without, _ = planned(config, cand, r, cal_sweeps, before, False)
        row.update(planned_g_without=without.mass_std_g, planned_cog_mm_without=without.cog_std_mm)
    return row


def summary(rows: list[dict], target_g: float) -> dict:
    rep = np.array([r["reported_g"] for r in rows])
    ratio = rep / np.array([r["planned_g"] for r in rows])
    z = np.log(ratio) / np.array([r["draw_spread"] for r in rows])
    return {"seeds": len(rows), "ratio_mean": float(ratio.mean()), "ratio_spread": float(ratio.std(ddof=1)),
            "draw_spread_median": float(np.median([r["draw_spread"] for r in rows])),
            "rms_z": float(math.sqrt(np.mean(z ** 2))), "mean_z": float(np.mean(z)),
            "p_over_mean": float(np.mean([r["p_over_mass"] for r in rows])), "over": int(np.sum(rep > target_g)),
            "inflation_mean": float(np.mean([r["inflation"] for r in rows])),
            "inflation_spread": float(np.std([r["inflation"] for r in rows], ddof=1)),
            **_ratios(rows)}


def _ratios(rows: list[dict]) -> dict:
    """reported / planned of the CoM's largest axis, and of the mass against the plan without the shared-baseline term
    (``--shared-baseline``): mean and relative spread over the seeds."""
    out = {}
    for key, rep, pred in (("cog", "reported_cog_mm", "planned_cog_mm"), ("without", "reported_g", "planned_g_without"),
                           ("cog_without", "reported_cog_mm", "planned_cog_mm_without")):
        if all(pred in r for r in rows):
            ratio = np.array([r[rep] / r[pred] for r in rows])
            out[f"ratio_{key}_mean"], out[f"ratio_{key}_spread"] = float(ratio.mean()), float(ratio.std(ddof=1))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(ap, seeds=40)
    ap.add_argument("--before", action="store_true", help="the plan's inflation as before session 18")
    ap.add_argument("--target-g", type=float, default=2.0, help="the mass target the chance is counted at")
    ap.add_argument("--shared-baseline", action="store_true",
                    help="calibrate on the procedure under test and let the run subtract the calibration's empty run")
    ap.add_argument("--json", metavar="OUT", help="write the per-seed rows and the summary here")
    args = ap.parse_args(argv)
    config, cal_config, run_config, cand = configs(args.robot, args)
    if args.shared_baseline:
        cal_config = run_config
    reference = parse_reference(args.calibrate_with)
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        r = one(config, cal_config, run_config, cand, seed, reference, args.before, args.target_g, args.shared_baseline)
        rows.append(r)
        without = f" ({r['planned_g_without']:.3f} without the term)" if "planned_g_without" in r else ""
        print(f"seed {seed:3d}: reported {r['reported_g']:.3f} g, planned {r['planned_g']:.3f} g{without}; CoM reported "
              f"{r['reported_cog_mm']:.3f} mm, planned {r['planned_cog_mm']:.3f} mm (inflation "
              f"{r['inflation']:.3f}, draws ±{100 * r['draw_spread']:.1f} %, P over {args.target_g:g} g "
              f"{100 * r['p_over_mass']:.0f} %)", flush=True)
    s = summary(rows, args.target_g)
    print(f"\n{args.robot}, {cand.describe()}, {'before' if args.before else 'now'}: {s['seeds']} seeds; rep/pred "
          f"{s['ratio_mean']:.3f} ± {100 * s['ratio_spread']:.1f} %; the plan's draws ±{100 * s['draw_spread_median']:.1f} %"
          f" (median); rms(z) {s['rms_z']:.2f}, mean z {s['mean_z']:+.2f}; mass σ over {args.target_g:g} g in {s['over']}"
          f" of {s['seeds']} against a mean P over of {100 * s['p_over_mean']:.1f} %; the plan's inflation "
          f"{s['inflation_mean']:.3f} ± {s['inflation_spread']:.3f}")
    for key, what in (("cog", "CoM rep/pred"), ("without", "mass rep/pred without the shared-baseline term"),
                      ("cog_without", "CoM rep/pred without it")):
        if f"ratio_{key}_mean" in s:
            print(f"{what}: {s[f'ratio_{key}_mean']:.3f} ± {100 * s[f'ratio_{key}_spread']:.1f} %")
    if args.json:
        Path(args.json).write_text(json.dumps({"procedure": cand.describe(), "before": args.before,
                                               "shared_baseline": args.shared_baseline, "summary": s,
                                               "runs": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
