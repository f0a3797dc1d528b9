"""Real recordings by outsiders: the agent's importer and solver on pairs of the same motion.

Not a test (CI and users do not have the data). Run
``.venv/bin/python -m benchmarks.realdata DIR [--robot ur10e] [--columns MAP] [--json OUT]``.

DIR is laid out like ``shared/realdata/ur10e-mamedov/``: a ``pairs.csv`` with the columns
``name,empty,loaded,mass_kg`` and the recordings it names. Each pair goes through exactly what
``payload-agent import`` does (``recording.motion_csv`` → ``evaluation.recorded_motion``), with
the current-to-torque constants the agent derives from the controller's own target signals:
nothing is taken from the stated truth. The table prints the mass error against the truth
the data's authors state (the only truth they state) and σ.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

from payload_agent.configuration.config import load_config
from payload_agent.configuration.paths import find_robot
from payload_agent.errors import PayloadAgentError
from payload_agent.evaluation.recorded_motion import analyse_recorded_motion
from payload_agent.recording.motion_csv import read_motion_csv

# the column layout of shared/realdata/ur10e-mamedov (its README: "Format")
MAMEDOV_COLUMNS = "timestamp,actual_q[6],actual_qd[6],actual_current[6],target_current[6],target_moment[6]"


def read_pairs(folder: Path) -> list[dict]:
    path = folder / "pairs.csv"
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    need = {"name", "empty", "loaded", "mass_kg"}
    if not rows or not need <= set(rows[0]):
        raise SystemExit(f"{path}: needs the columns {', '.join(sorted(need))}")
    return rows


def run_pair(folder: Path, pair: dict, kin, columns: str | None) -> dict:
    t0 = time.perf_counter()
    empty = read_motion_csv(folder / pair["empty"], columns)
    loaded = read_motion_csv(folder / pair["loaded"], columns)
    r = analyse_recorded_motion(empty, loaded, kin).to_json()
    truth = float(pair["mass_kg"])
    return {"name": pair["name"], "truth_mass_kg": truth, "mass_kg": r["mass_kg"], "mass_std_kg": r["mass_std_kg"],
            "mass_error_percent": 100 * (r["mass_kg"] / truth - 1), "cog_mm": r["cog_mm"], "cog_std_mm": r["cog_std_mm"],
            "inertia_kgm2": r["inertia_com_kgm2"], "inertia_unsupported": r["inertia_unsupported"],
            "gain_source": r["gain_source"], "gains_nm_per_unit": r["gains_nm_per_unit"], "joints_used": r["joints_used"],
            "alignment": r["alignment"], "dropped_rows": r["dropped_rows"], "seconds": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a folder with pairs.csv and the recordings it names")
    p.add_argument("--robot", default="ur10e", help="robot YAML or name whose kinematics to use (default ur10e)")
    p.add_argument("--columns", default=MAMEDOV_COLUMNS,
                   help="column map for files without a header (default: the ur10e-mamedov layout); '' for files "
                        "with an RTDE header")
    p.add_argument("--json", metavar="OUT", help="also write the pairs as JSON")
    args = p.parse_args(argv)
    kin = load_config(find_robot(args.robot)).robot.kinematics
    out, failed = [], 0
    for pair in read_pairs(args.folder):
        try:
            out.append(run_pair(args.folder, pair, kin, args.columns or None))
        except PayloadAgentError as exc:
            failed += 1
            print(f"{pair['name']}: no result: {exc}", file=sys.stderr)
    print(f"\n{args.folder} ({args.robot} kinematics), constants from the controller's target signals:\n")
    print("| pair | truth kg | mass kg | σ kg | error | error/σ | CoM mm (± σ) | joints | inertia |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in out:
        cog = ", ".join(f"{c:.0f}±{s:.0f}" for c, s in zip(r["cog_mm"], r["cog_std_mm"]))
        err = r["mass_kg"] - r["truth_mass_kg"]
        print(f"| {r['name']} | {r['truth_mass_kg']:.3f} | {r['mass_kg']:.4f} | {r['mass_std_kg']:.4f} | "
              f"{r['mass_error_percent']:+.2f} % | {err / r['mass_std_kg']:+.2f} | {cog} | "
              f"{','.join(map(str, r['joints_used']))} | {'given' if r['inertia_kgm2'] else 'not supported'} |")
    for r in out:
        k = ", ".join("-" if g is None else f"{g:.3f}" for g in r["gains_nm_per_unit"])
        print(f"{r['name']}: constants [{k}] N·m/A; shift {r['alignment']['shift_s']:+.3f} s, angles match "
              f"{r['alignment']['angle_rms_mrad']:.2f} mrad rms; {r['seconds']:.1f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"folder": str(args.folder), "pairs": out}, indent=2))
    return 1 if failed or not out else 0


if __name__ == "__main__":
    raise SystemExit(main())
