"""Seeded runs of the whole product on a simulated robot: is there a bias, and does the σ cover it?

Not a test: each run is a full session (runner, driver, simulated controller over its real protocol),
with its own simulation seed and its own empty-flange run, so the runs' errors are independent. It
prints every run's error against the simulation's truth with the reported σ, then per quantity the
mean error (a bias shows here), its standard error, rms(error/σ) and the share of 95 % intervals that
hold the truth.

    .venv/bin/python -m benchmarks.seeded_runs --robot sim-ur5e-modbus --runs 10 [--json OUT]
        [--target-std G,MM [--baseline] [--calibrate [--calibrate-with KG:X,Y,Z] [--calibrate-speed PERCENT]
        [--calibrate-procedure NAME|FILE] [--calibrate-sweep-deg FROM,TO] [--calibrate-travel PERCENT]
        [--calibrate-accel PERCENT] [--calibrate-park]] [--reuse-baseline]] [--driver-option KEY=VALUE] [--dh-error-mm MM]

``--target-std``: each run first does what ``plan --target-std G,MM`` does (for the simulation's payload,
the approach from its start_deg counted) and runs the chosen procedure; the table then adds the
chosen robot time and the predicted σ beside the reported one (plan matches run, issue 22). The predicted σ is a
typical run's (the median over the plan's draws); a run whose wrist term (a tool cable's spring) enters its σ
reports more, so the runs with and without it are shown apart, beside the plan's chance of the term.
``--baseline``: each seed's state gets an empty-flange baseline of the YAML's procedure first (the plan measures
the effort noise and the stream's samples per second in it; the run still records its own empty run).
``--calibrate``: each seed's state gets a drive-gain calibration first (``calibrate`` with a 3 kg
reference at 0, 0, 80 mm, the default procedure), so the plan and the run use it. ``--calibrate-with``
another reference (a centre of mass off the flange axis loads joint 6 too, so its gain is fitted),
``--calibrate-speed`` the calibration's sweep speed (the robot YAML's procedure otherwise), ``--calibrate-procedure``
its procedure (the YAML's otherwise), ``--calibrate-sweep-deg``/``--calibrate-travel``/``--calibrate-accel`` its
range, travel speed and acceleration (as ``calibrate --sweep-deg``, ``--travel-speed-percent``, ``--accel-percent``).
``--reuse-baseline``: the run reuses the stored baseline when its plan has the baseline's fingerprint, as ``run`` does (the chosen candidate is
then the calibration's plan, ``session.stored_candidate``), the inertia part off for the whole seed so that the
calibration's, the plan's and the run's plans agree. ``--start-where-calibration-ended``: the plan (its approach) and
the run start where the calibration's plan ended, as after ``calibrate`` with the tool swapped in place (the run that
reuses the baseline then has its cable's rest there); ``--start-where-calibration-began``: at its first pose (the robot
put there by the simulation, a stand-in); ``--calibrate-park``: the calibration runs with ``--park`` (it ends at its
plan's first pose) and the plan and the run start where its resting-pose record says the arm stands. ``--calibrate-on-chosen`` (with ``--target-std``, instead of ``--calibrate``):
plan, calibrate on the chosen procedure (its speeds, range and accelerations; the inertia part off: ``calibrate
--robot`` the written file), predict that procedure again with the calibration and run it with the stored baseline,
as ``run`` does without ``--fresh-baseline``: the run subtracts the calibration's empty run, and its σ and the
plan's carry their correlation (``evaluation.shared_baseline``); the JSON says per seed whether both did. ``--dh-error-mm``: each
seed's simulated arm has its non-zero DH lengths off by up to that (uniform, drawn from the seed) while the agent
keeps the YAML's; the JSON then holds the drawn errors and the plan's DH-length term (``pred_length_std``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.errors import DataError, PayloadAgentError
from payload_agent.evaluation import noise_inflation
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("mass g", "CoM x mm", "CoM y mm", "CoM z mm")


DEFAULT_REFERENCE = (3.0, (0.0, 0.0, 80.0))  # kg, mm
DRIVER_OVERRIDES: dict = {}  # driver keys set for every seed (``--driver-option``)


def parse_reference(text: str | None) -> tuple:
    """``--calibrate-with KG:X,Y,Z`` as (kg, (x, y, z) mm); the default reference without one."""
    if not text:
        return DEFAULT_REFERENCE
    kg, cog = text.split(":")
    return float(kg), tuple(float(v) for v in cog.split(","))


def seed_config(robot: str, seed: int, storage: Path, calibrate: bool = False, reference: tuple = DEFAULT_REFERENCE,
                calibrate_speed: float | None = None, retry_sweeps: int = 0, baseline: bool = False,
                dh_error_mm: float = 0.0, calibrate_procedure: str | None = None, calibrate_motion: tuple | None = None,
                inertia: bool = True, calibrate_park: bool = False):
    """The shipped simulated robot's config for one seed, its state in ``storage`` (an empty-flange baseline of the
    YAML's procedure stored, then calibrated, first when asked: on ``calibrate_procedure``, a procedure's name or
    file, as ``calibrate --procedure``, else the YAML's); ``dh_error_mm``: the simulated arm's DH lengths off
    by up to that (``simulation.dh_length_error_mm``, drawn from the seed: another arm per seed)."""
    data = yaml.safe_load((ROOT / "configs" / f"{robot}.yaml").read_text())
    data["simulation"]["seed"] = seed
    if dh_error_mm > 0:
        data["simulation"]["dh_length_error_mm"] = dh_error_mm
    data["robot"]["name"] = f"{robot}-seed{seed}"
    data["storage"] = {"runs_dir": str(storage / "runs"), "state_dir": str(storage / "state")}
    data.pop("watch", None)
    if DRIVER_OVERRIDES:  # ``--driver-option KEY=VALUE``: a harness setting for a loaded host, printed with the results
        data["driver"].update(DRIVER_OVERRIDES)
    if not inertia:  # the whole seed without the inertia part (calibration, plan and run alike)
        data["procedure"]["inertia"] = False
    config = parse_config(data, source=f"configs/{robot}.yaml", base_dir=ROOT / "configs")
    if baseline:  # `payload-agent baseline`: the plan then measures the noise and the stream in it
        run_identification(config, RunOptions(mode="baseline", **_quiet(retry_sweeps)), _silent())
    if calibrate:
        from payload_agent.calibrate_args import with_procedure, with_speed

        from payload_agent.calibrate_args import with_sweep_and_motion

        cal = with_procedure(with_speed(config, calibrate_speed), calibrate_procedure)
        calibrate_on(with_sweep_and_motion(cal, *(calibrate_motion or ())), reference, retry_sweeps, calibrate_park)
    return config


def calibrate_on(cal_config, reference: tuple, retry_sweeps: int, park: bool = False) -> None:
    """``payload-agent calibrate`` with ``cal_config``'s procedure and the reference (kg, (x, y, z) mm); ``park``: with
    ``--park``, ending at its plan's first pose."""
    from payload_agent.types import PayloadSetting

    kg, cog_mm = reference
    run_identification(cal_config, RunOptions(mode="calibrate", reference=PayloadSetting(
        kg, tuple(c / 1000.0 for c in cog_mm)), park=park, **_quiet(retry_sweeps)), _silent(),
        SimulatedCellUse(on_cell=lambda cell: cell.change_tool(kg, tuple(cog_mm))))


def _quiet(retry_sweeps: int) -> dict:
    return dict(assume_yes=True, report=False, retry_sweeps=retry_sweeps)


def _silent() -> OperatorUI:
    return OperatorUI(progress=False, out=lambda *_: None)


def one_run(robot: str, seed: int, storage: Path, target: str | None = None, calibrate: bool = False,
            reference: tuple = DEFAULT_REFERENCE, calibrate_speed: float | None = None, retry_sweeps: int = 0,
            baseline: bool = False, dh_error_mm: float = 0.0, calibrate_procedure: str | None = None,
            calibrate_on_chosen: bool = False, calibrate_motion: tuple | None = None, reuse_baseline: bool = False,
            start_where_calibration_ended: bool = False, start_where_calibration_began: bool = False,
            calibrate_park: bool = False) -> dict:
    import dataclasses

    config = seed_config(robot, seed, storage, calibrate, reference, calibrate_speed, retry_sweeps, baseline,
                         dh_error_mm, calibrate_procedure, calibrate_motion, inertia=not reuse_baseline,
                         calibrate_park=calibrate_park)
    if calibrate_park or start_where_calibration_ended or start_where_calibration_began:  # the tool mounted there
        start = (resting_deg(config) if calibrate_park  # each session's simulated arm starts at start_deg: there
                 else calibration_end_deg(config, 0 if start_where_calibration_began else -1))
        config = dataclasses.replace(config, simulation=dataclasses.replace(config.simulation, start_deg=tuple(start)))
    quiet, ui = _quiet(retry_sweeps), _silent()
    plan: dict = {}
    calibrated_on = None  # the first choice, where the calibration is made on it (``--calibrate-on-chosen``)
    if calibrate_on_chosen:  # the run below is the candidate's config, the inertia part off: so is the plan's view of it
        config = dataclasses.replace(config, procedure=dataclasses.replace(config.procedure, inertia=None))
    if target:
        from payload_agent.evaluation import design
        from payload_agent.evaluation.planned_baseline import reusing_run_mount
        from payload_agent.session import target as targets

        sim = config.simulation
        payload = targets.ExpectedPayload(sim.payload.mass_kg, tuple(sim.payload.cog_mm), "the simulation's")
        choice, _ = targets.plan_for_target(config, target, payload, np.radians(sim.start_deg))
        if calibrate_on_chosen and choice.best is not None:  # then its prediction after the calibration, and run it
            first = choice.best.candidate
            calibrate_on(design.with_candidate(config, first), reference, retry_sweeps)
            again = design.predict(config, first, noise_model(config), design.nominal_theta(
                sim.payload.mass_kg, sim.payload.cog_mm), start_q=np.radians(sim.start_deg))
            choice, calibrated_on = design.Choice(again, [again]), first.describe()
        if choice.best is None:
            fastest = min((p for p in choice.table if p.usable), key=lambda p: p.mass_std_g, default=None)
            raise DataError(f"plan --target-std {target}: no procedure meets it" + (
                "" if fastest is None else f" (least mass σ {fastest.mass_std_g:.2f} g: {fastest.candidate.describe()})"))
        best = choice.best
        config = design.with_candidate(config, best.candidate)
        noise = noise_model(config)
        shared = noise.shared_baseline is not None and noise.shared_baseline.reused_by(config)
        terms, _, wrist, _ = design.terms_and_wrist_model(config, design.plan_for(config, best.candidate), noise,
                                                          design.nominal_theta(sim.payload.mass_kg, sim.payload.cog_mm),
                                                          shared=shared, mount_rad=reusing_run_mount(
            config, design.plan_for(config, best.candidate), np.radians(sim.start_deg))
                                                          if best.candidate.stored_baseline else None)
        plan = {"procedure": best.candidate.describe(), "robot_time_s": best.robot_time_s,
                "pred_length_std": list(term_sigmas(terms["lengths"], sim)),
                # the torque-gain term of the clusters standing at the calibration's angles (``planned_scatter``)
                "pred_scatter_std": list(term_sigmas(terms["scatter"], sim)),
                "approach_s": best.approach_s, "pred_std": [best.mass_std_g, best.cog_std_mm],
                "pred_rms_std": [best.mass_rms_std_g, best.cog_rms_std_mm],
                "p_over_target": best.p_over(*targets.parse_target(target)),
                "pred_wrist_share": float(np.mean(wrist.a > 0)),  # the plan's chance the run's wrist term is in σ
                "pred_shared_baseline": bool(shared), "stored_plan": best.candidate.stored_baseline, "calibrated_on": calibrated_on, "pred_baseline_cut": list(term_sigmas(-terms["baseline"], sim))}
    planned_share, planned = stream_share(config), noise_inflation.stored(config)
    reuse = calibrate_on_chosen or reuse_baseline
    outcome = run_identification(config, RunOptions(fresh_baseline=not reuse, **quiet), ui)
    try:  # what the run's σ follows: its own robust-to-white ratio (a diagnostic: a run it cannot fit still counts)
        own = noise_inflation.of_run(config, outcome.run_dir)
        ratio = [own.mass_ratio, own.cog_ratio]
    except DataError:
        ratio = [float("nan")] * 2
    plan.update(kept_share=stream_share(config, outcome.run_dir), planned_share=planned_share,
                inflation=ratio, planned_inflation=planned.ratio)
    est, truth = outcome.result.primary, outcome.truth
    err = [1000 * (est.mass_kg - truth["mass_kg"]), *(np.asarray(est.cog_mm) - truth["cog_mm"])]
    std = [1000 * est.mass_std_kg, *(1000 * np.asarray(est.cog_std_m))]
    if config.simulation.dh_length_error_mm > 0:  # the drawn arm's length errors (mm; a then d per DH row)
        from payload_agent.fakes.arms import SPECS, simulated_spec

        drawn, nominal = simulated_spec(config.simulation).dh, SPECS[config.simulation.arm]().dh
        plan["dh_length_errors_mm"] = [round(1000.0 * (x.a_m - n.a_m), 4) for x, n in zip(drawn, nominal)] + [
            round(1000.0 * (x.d_m - n.d_m), 4) for x, n in zip(drawn, nominal)]
    # the wrist term's note (a cable spring's presence test, or the free offsets'): the per-seed CoM σ follows it
    wrist = [n for n in est.notes if n.startswith(("a tool cable", "constant wrist torques"))]
    return {"seed": seed, "error": [float(e) for e in err], "std": [float(s) for s in std],
            "passed": bool(outcome.result.quality.get("passed")), "wrist_note": wrist[0] if wrist else None,
            "wrist_weight": wrist_weight(wrist[0] if wrist else None),
            "shared_baseline": any("empty baseline" in n for n in est.notes),
            # the calibration's per-angle gain errors taken off still rows standing at its angles (``calibration_clusters``)
            "corrected_clusters": any(n.startswith("still rows standing at the calibration's angles") for n in est.notes),
            "reused_baseline": "from_baseline" in json.loads((outcome.run_dir / "manifest.json").read_text())[
                "phases"]["empty"], **plan}


def calibration_end_deg(config, move: int = -1) -> list[float]:
    """Where the stored calibration's plan ended (its empty run became the stored baseline: the last move's target), or
    began (``move`` 0: its first pose, the approach's target)."""
    from payload_agent.recording.rundata import load_manifest
    from payload_agent.recording.state import RobotState

    return [float(v) for v in load_manifest(RobotState.for_config(config).baseline_dir)["plan"][move]["target_deg"]]


def resting_deg(config) -> list[float]:
    """Where our last completed motion left the arm (the resting-pose record the calibration wrote), degrees."""
    from payload_agent.recording import resting_pose
    from payload_agent.recording.state import RobotState

    rec = resting_pose.load(RobotState.for_config(config).root)
    assert rec is not None and rec.q_to_rad is None, "the calibration left no record of a completed motion"
    return [float(np.degrees(v)) for v in rec.q_rad]


def wrist_weight(note: str | None) -> float:
    """The share of the wrist term a run put into its σ, read from its note (``systematics.cable_spring.note``,
    ``wrist_terms``): 0 without the note (the run's test statistic below its null mean), 1 where a cable was found
    or declared, else the weight it states (the free offsets' shrink)."""
    import re

    if not note:
        return 0.0
    share = re.search(r"([0-9.]+) × (?:of it|as measured)", note)
    return float(share.group(1)) if share else 1.0


def noise_model(config):
    """The plan's noise model, as ``plan --target-std`` reads it."""
    from payload_agent.session import target as targets

    return targets.noise_for(config)[0]


def term_sigmas(cov: np.ndarray, sim) -> tuple[float, float]:
    """(σ mass g, σ CoM largest axis mm) of one term of the plan, for the simulation's payload."""
    from payload_agent.evaluation import design
    from payload_agent.solvers.wls import cog_with_covariance

    theta = design.nominal_theta(sim.payload.mass_kg, sim.payload.cog_mm)
    _, cov_c = cog_with_covariance(theta, cov)
    return 1000.0 * float(np.sqrt(max(cov[0, 0], 0.0))), 1000.0 * float(np.sqrt(max(np.max(np.diag(cov_c)), 0.0)))


def stream_share(config, run_dir: Path | None = None) -> float:
    """The share of its nominal samples per robot second the run's stream kept (``run_dir``), or that the plan
    assumes from the stored runs (None): a plan that misses on a thin stream shows here."""
    from payload_agent.session import stream_density
    from payload_agent.session.connection import build_driver

    nominal = stream_density.nominal_period_s(config, build_driver(config))
    return stream_density.delivered(config, nominal, None if run_dir is None else [run_dir]).kept_share


def _list(values) -> str:
    return " ".join(f"{v:.2f}" for v in values)


def summarise(runs: list[dict]) -> list[dict]:
    err = np.array([r["error"] for r in runs])
    std = np.array([r["std"] for r in runs])
    z = err / std
    return [{"quantity": name, "mean_error": float(err[:, k].mean()),
             "stderr_of_mean": float(err[:, k].std(ddof=1) / np.sqrt(len(runs))) if len(runs) > 1 else None,
             "mean_sigma": float(std[:, k].mean()), "rms_z": float(np.sqrt(np.mean(z[:, k] ** 2))),
             "coverage_95": float(np.mean(np.abs(z[:, k]) <= 1.96))} for k, name in enumerate(NAMES)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", default="sim-ur5e-modbus", help="a shipped simulated robot (configs/NAME.yaml)")
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--first-seed", type=int, default=1)
    p.add_argument("--json", metavar="OUT", help="also write the runs and the summary as JSON")
    p.add_argument("--target-std", metavar="G,MM", help="run the procedure `plan --target-std` chooses")
    p.add_argument("--baseline", action="store_true",
                   help="store an empty-flange baseline of the YAML's procedure first (each seed), as `baseline` does")
    p.add_argument("--calibrate", action="store_true", help="calibrate the drive gains first (each seed)")
    p.add_argument("--calibrate-with", metavar="KG:X,Y,Z", help="the calibration's reference (default 3:0,0,80)")
    p.add_argument("--calibrate-speed", type=float, metavar="PERCENT", help="the calibration's sweep speed")
    p.add_argument("--calibrate-procedure", metavar="NAME|FILE",
                   help="the calibration's procedure (as `calibrate --procedure`; default the YAML's)")
    p.add_argument("--calibrate-on-chosen", action="store_true",
                   help="with --target-std: calibrate on the chosen procedure, predict it again, run it with the stored "
                        "baseline")
    p.add_argument("--calibrate-sweep-deg", metavar="FROM,TO", help="the calibration's sweep range (the YAML's otherwise)")
    p.add_argument("--calibrate-travel", type=float, metavar="PERCENT", help="the calibration's travel speed")
    p.add_argument("--calibrate-accel", type=float, metavar="PERCENT", help="the calibration's acceleration")
    p.add_argument("--reuse-baseline", action="store_true",
                   help="the run reuses the stored baseline when its plan has its fingerprint, as `run` does (else "
                        "each run records its own empty run); the inertia part off for the whole seed")
    p.add_argument("--start-where-calibration-ended", action="store_true",
                   help="with --calibrate: the plan and the run start where the calibration's plan ended (the tool "
                        "mounted there, as after `calibrate` with nothing moved since), not at simulation.start_deg")
    p.add_argument("--start-where-calibration-began", action="store_true",
                   help="with --calibrate: the plan and the run start at the calibration plan's first pose (the robot "
                        "parked there for the tool change)")
    p.add_argument("--calibrate-park", action="store_true",
                   help="with --calibrate: `calibrate --park` (its last run ends at its plan's first pose); the plan and "
                        "the run then start where that left the arm (the resting-pose record), as on a real arm with "
                        "the tool changed there")
    p.add_argument("--retry-sweeps", type=int, default=0, metavar="N",
                   help="redo a sweep whose stream had a hole, up to N times (as `run --retry-sweeps`)")
    p.add_argument("--dh-error-mm", type=float, default=0.0, metavar="MM",
                   help="the simulated arm's DH lengths off by up to MM (uniform, per seed: simulation.dh_length_error_mm)")
    p.add_argument("--driver-option", action="append", default=[], metavar="KEY=VALUE",
                   help="set a driver key for every seed (a Modbus timeout_s on a loaded host); printed with the results")
    args = p.parse_args(argv)
    reference = parse_reference(args.calibrate_with)
    motion = (args.calibrate_sweep_deg, args.calibrate_travel, args.calibrate_accel)  # as `calibrate --sweep-deg` ...
    for item in args.driver_option:
        key, _, value = item.partition("=")
        DRIVER_OVERRIDES[key] = yaml.safe_load(value)
    if DRIVER_OVERRIDES:
        print(f"driver keys set for this benchmark: {DRIVER_OVERRIDES}", flush=True)
    runs, failed = [], []
    for seed in range(args.first_seed, args.first_seed + args.runs):
        try:
            with tempfile.TemporaryDirectory(prefix="seeded-runs-") as tmp:
                r = one_run(args.robot, seed, Path(tmp), args.target_std, args.calibrate, reference,
                            args.calibrate_speed, args.retry_sweeps, args.baseline, args.dh_error_mm,
                            args.calibrate_procedure, args.calibrate_on_chosen, motion, args.reuse_baseline,
                            args.start_where_calibration_ended, args.start_where_calibration_began,
                            args.calibrate_park)
        except PayloadAgentError as exc:  # a run that did not end in a result is reported, not averaged
            failed.append({"seed": seed, "error": str(exc)})
            print(f"seed {seed:3d}: no result (exit {exc.exit_code}): {str(exc)[:160]}", flush=True)
            continue
        runs.append(r)
        print(f"seed {seed:3d}: " + "  ".join(f"{n} {e:+7.2f} ± {s:5.2f}" for n, e, s in zip(NAMES, r["error"], r["std"]))
              + ("" if r["passed"] else "  (quality gate failed)")
              + (f"  | {r['procedure']}: {r['robot_time_s']:.0f} s ({r['approach_s']:.0f} s approach), predicted "
                 f"σ {r['pred_std'][0]:.2f} g / {r['pred_std'][1]:.2f} mm (rms {r['pred_rms_std'][0]:.2f} / "
                 f"{r['pred_rms_std'][1]:.2f}, P over {100 * r['p_over_target']:.0f} %)" if "procedure" in r else "")
              + f"  | stream kept {100 * r['kept_share']:.0f} % (planned {100 * r['planned_share']:.0f} %)"
              + f"  | robust/white σ m {r['inflation'][0]:.2f} c {r['inflation'][1]:.2f} (planned "
                f"{r['planned_inflation']:.2f})", flush=True)
    if len(runs) < 2:
        print("fewer than two runs ended in a result: no summary")
        return 1
    summary = summarise(runs)
    print(f"\n{args.robot}, {len(runs)} seeded runs (each with its own empty run)"
          + (f", {len(failed)} without a result" if failed else "") + ":")
    print("| quantity | mean error | ± s.e. | mean σ | rms(err/σ) | 95 % coverage |\n|---|---|---|---|---|---|")
    for s in summary:
        se = f"{s['stderr_of_mean']:.2f}" if s["stderr_of_mean"] is not None else "-"
        print(f"| {s['quantity']} | {s['mean_error']:+.2f} | {se} | {s['mean_sigma']:.2f} | {s['rms_z']:.2f} "
              f"| {s['coverage_95']:.2f} |")
    if args.target_std:
        pm = np.array([r["pred_std"] for r in runs])
        pr = np.array([r["pred_rms_std"] for r in runs])
        rep_m = np.array([r["std"][0] for r in runs])
        rep_c = np.array([max(r["std"][1:]) for r in runs])
        t = np.array([r["robot_time_s"] for r in runs])
        a = np.array([r["approach_s"] for r in runs])
        print(f"\nplan --target-std {args.target_std}{' after calibrate' if args.calibrate else ''}: robot time "
              f"{t.mean():.1f} s ({a.mean():.1f} s of it the approach); predicted σ mass {pm[:, 0].mean():.2f} g, "
              f"reported {rep_m.mean():.2f} g (ratio {np.mean(pm[:, 0] / rep_m):.2f}); predicted σ CoM (largest "
              f"axis) {pm[:, 1].mean():.2f} mm, reported {rep_c.mean():.2f} mm (ratio {np.mean(pm[:, 1] / rep_c):.2f})")
        grams, mm = (float(v) for v in args.target_std.split(","))
        clean = np.array([r.get("wrist_weight", 0.0) == 0.0 for r in runs])
        if "pred_wrist_share" in runs[0]:  # the median is the run without the wrist term; the term's frequency apart
            ratio_c = pm[:, 1] / rep_c
            print(f"the run's wrist term in σ in {int(np.sum(~clean))} of {len(runs)} runs (the plan's chance "
                  f"{100 * np.mean([r['pred_wrist_share'] for r in runs]):.0f} %); pred/rep c in the runs without it "
                  f"{_list(ratio_c[clean])}, with it {_list(ratio_c[~clean])}")
        if "pred_shared_baseline" in runs[0]:  # the calibration's empty run subtracted: by the plan, by the run
            print(f"the calibration's empty run subtracted: planned for {sum(r['pred_shared_baseline'] for r in runs)},"
                  f" by the run in {sum(r['shared_baseline'] for r in runs)} of {len(runs)} runs")
        within = lambda pred, rep: int(np.sum(np.abs(pred / rep - 1.0) <= 0.3))  # noqa: E731
        print(f"predicted = median of the run's σ: ratio pred/rep per seed m {_list(pm[:, 0] / rep_m)}, c "
              f"{_list(pm[:, 1] / rep_c)}; within ±30 % m {within(pm[:, 0], rep_m)}, c {within(pm[:, 1], rep_c)} of "
              f"{len(runs)}\npredicted = root of the expected variance (before): mean ratio m "
              f"{np.mean(pr[:, 0] / rep_m):.2f}, c {np.mean(pr[:, 1] / rep_c):.2f}; within ±30 % m "
              f"{within(pr[:, 0], rep_m)}, c {within(pr[:, 1], rep_c)}\nthe run's σ over the target: m "
              f"{int(np.sum(rep_m > grams))}, c {int(np.sum(rep_c > mm))}, either "
              f"{int(np.sum((rep_m > grams) | (rep_c > mm)))} of {len(runs)} (predicted P over "
              f"{100 * np.mean([r['p_over_target'] for r in runs]):.0f} %)")
    if args.json:
        Path(args.json).write_text(json.dumps({"robot": args.robot, "runs": runs, "failed": failed, "summary": summary}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
