"""Seeded runs of the whole product on a simulated robot: is there a bias, and does the σ cover it?

Not a test: each run is a full session (runner, driver, simulated controller over its real protocol),
with its own simulation seed and its own empty-flange run, so the runs' errors are independent. It
prints every run's error against the simulation's truth with the reported σ, then per quantity the
mean error (a bias shows here), its standard error, rms(error/σ) and the share of 95 % intervals that
hold the truth.

    .venv/bin/python -m benchmarks.seeded_runs --robot sim-ur5e-modbus --runs 10 [--json OUT]
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
from payload_agent.errors import PayloadAgentError
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("mass g", "CoM x mm", "CoM y mm", "CoM z mm")


def one_run(robot: str, seed: int, storage: Path) -> dict:
    data = yaml.safe_load((ROOT / "configs" / f"{robot}.yaml").read_text())
    data["simulation"]["seed"] = seed
    data["robot"]["name"] = f"{robot}-seed{seed}"
    data["storage"] = {"runs_dir": str(storage / "runs"), "state_dir": str(storage / "state")}
    data.pop("watch", None)
    config = parse_config(data, source=f"configs/{robot}.yaml", base_dir=ROOT / "configs")
    outcome = run_identification(config, RunOptions(assume_yes=True, fresh_baseline=True, report=False),
                                         OperatorUI(progress=False, out=lambda *_: None))
    est, truth = outcome.result.primary, outcome.truth
    err = [1000 * (est.mass_kg - truth["mass_kg"]), *(np.asarray(est.cog_mm) - truth["cog_mm"])]
    std = [1000 * est.mass_std_kg, *(1000 * np.asarray(est.cog_std_m))]
    return {"seed": seed, "error": [float(e) for e in err], "std": [float(s) for s in std],
            "passed": bool(outcome.result.quality.get("passed"))}


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
    args = p.parse_args(argv)
    runs, failed = [], []
    for seed in range(args.first_seed, args.first_seed + args.runs):
        try:
            with tempfile.TemporaryDirectory(prefix="seeded-runs-") as tmp:
                r = one_run(args.robot, seed, Path(tmp))
        except PayloadAgentError as exc:  # a run that did not end in a result is reported, not averaged
            failed.append({"seed": seed, "error": str(exc)})
            print(f"seed {seed:3d}: no result (exit {exc.exit_code}): {str(exc)[:160]}", flush=True)
            continue
        runs.append(r)
        print(f"seed {seed:3d}: " + "  ".join(f"{n} {e:+7.2f} ± {s:5.2f}" for n, e, s in zip(NAMES, r["error"], r["std"]))
              + ("" if r["passed"] else "  (quality gate failed)"), flush=True)
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
    if args.json:
        Path(args.json).write_text(json.dumps({"robot": args.robot, "runs": runs, "failed": failed, "summary": summary}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
