"""`payload-agent import`: the payload from two recordings of one motion the agent did not make.

Also what `solve` does with a folder that `import` wrote. Nothing here connects to a robot.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from payload_agent.configuration.config import Config, config_snapshot, load_config
from payload_agent.configuration.paths import find_robot
from payload_agent.errors import ConfigError, DataError
from payload_agent.output.console import Console

GAIN_CHOICES = ("controller", "config")


def load_robot(args) -> Config:
    return load_config(find_robot(args.robot))


def _kinematics(snapshot: Mapping[str, Any], source: str):
    from payload_agent.configuration.recorded import parse_recorded_config

    return parse_recorded_config(snapshot, {"effort_unit": "Nm"}, source).robot.kinematics


def _analyse(run, kin):
    from payload_agent.evaluation.recorded_motion import analyse_recorded_motion
    from payload_agent.recording.motion_csv import read_motion_csv

    empty = read_motion_csv(run.recording("empty"), run.column_map)
    loaded = read_motion_csv(run.recording("loaded"), run.column_map)
    g = run.gains or {}
    return analyse_recorded_motion(empty, loaded, kin, gains_nm_per_unit=g.get("gains_nm_per_unit"),
                                   gains_source=g.get("source", ""))


def _gains_choice(choice: str, config) -> dict | None:
    if choice == "controller":
        return None
    if config.effort.unit != "A":
        raise ConfigError("effort.unit", f"--gains config needs gains for motor current (A); the robot YAML's are "
                                         f"per {config.effort.unit}")
    return {"source": f"robot YAML effort.gains_nm_per_unit ({config.source})",
            "gains_nm_per_unit": [float(v) for v in config.effort.gains_nm_per_unit]}


def describe(result: Mapping[str, Any], sources: Mapping[str, str]) -> str:
    """The lines a person reads: what was read, how it matched, the constants, the payload."""
    lines = []
    for role in ("empty", "loaded"):
        dropped = result["dropped_rows"].get(role, [])
        lines.append(f"{role.capitalize():6} {sources[role]}" + (f" ({len(dropped)} rows dropped: {dropped[0]}"
                                                                  + (", …" if len(dropped) > 1 else "") + ")"
                                                                  if dropped else ""))
    a = result["alignment"]
    lines.append(f"Aligned: loaded run shifted {a['shift_s']:+.3f} s; joint angles match to {a['angle_rms_mrad']:.2f} "
                 f"mrad rms ({a['angle_max_mrad']:.2f} at most), {a['samples']} samples every {1000 * a['period_s']:.0f} ms")
    tc = result.get("torque_constants")
    if tc:
        parts = [f"j{j + 1} {k:.3f} ± {s:.3f}" if ok else f"j{j + 1} not determined"
                 for j, (k, s, ok) in enumerate(zip(tc["k_nm_per_a"], tc["std_nm_per_a"], tc["determined"]))]
        lines.append(f"Current-to-torque constants (N·m/A) from the {tc['source']}: " + ", ".join(parts))
    else:
        lines.append(f"Gains: {result['gain_source']}")
    lines.append(f"Joints used: {', '.join(str(j) for j in result['joints_used'])}")
    lines.append(f"Mass            {result['mass_kg']:.4f} kg ± {result['mass_ci95_kg']:.4f} (95 %)")
    cog, std = result["cog_mm"], result["cog_std_mm"]
    lines.append("Centre of mass  [" + ", ".join(f"{v:.1f}" for v in cog) + "] mm ± ["
                 + ", ".join(f"{1.96 * v:.1f}" for v in std) + "] (95 %), flange axes")
    if result["inertia_com_kgm2"] is not None:
        I, s = np.asarray(result["inertia_com_kgm2"]), np.asarray(result["inertia_com_std_kgm2"])
        lines.append("Inertia about the centre of mass (kg·m², flange axes): "
                     f"Ixx {I[0, 0]:.4f} ± {s[0, 0]:.4f}, Iyy {I[1, 1]:.4f} ± {s[1, 1]:.4f}, "
                     f"Izz {I[2, 2]:.4f} ± {s[2, 2]:.4f}, Ixy {I[0, 1]:.4f}, Ixz {I[0, 2]:.4f}, Iyz {I[1, 2]:.4f}")
        ur, pr = result["forms"]["ur"], result["forms"]["principal"]
        lines.append("UR set_target_payload inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] kg·m² at the CoG: ["
                     + ", ".join(f"{v:.5f}" for v in ur["inertia_kgm2"]) + "]")
        lines.append("Principal (KUKA load data, OPC 40010 LoadType): A, B, C " + ", ".join(f"{v:.1f}" for v in
                     pr["abc_deg"]) + " °; JX, JY, JZ " + ", ".join(f"{v:.5f}" for v in pr["j_kgm2"]) + " kg·m²")
    else:
        lines.append(f"Inertia: not given ({result['inertia_unsupported']['reason']})")
    lines += [f"Note: {n}" for n in result["notes"]]
    return "\n".join(lines)


def cmd_import(args, con: Console) -> int:
    from payload_agent.recording.imported_run import create_imported_run, write_result

    for key, path in (("--empty", args.empty), ("--loaded", args.loaded)):
        if not Path(path).is_file():
            raise ConfigError(key, f"{path}: no such file")
    config = load_robot(args)
    gains = _gains_choice(args.gains, config)
    from payload_agent.recording.motion_csv import read_motion_csv

    for key, path in (("--empty", args.empty), ("--loaded", args.loaded)):  # read once before a folder is made
        read_motion_csv(path, args.columns)
    run = create_imported_run(Path(config.storage.runs_dir), config.robot.name, config_snapshot(config),
                              {"empty": Path(args.empty), "loaded": Path(args.loaded)}, args.columns, gains)
    con.detail(f"Run folder: {run.run_dir}")
    try:
        result = _analyse(run, config.robot.kinematics).to_json()
    except DataError as exc:
        raise DataError(f"{exc} (the recordings are kept in {run.run_dir})") from None
    path = write_result(run.run_dir, result)
    con.say(describe(result, {"empty": args.empty, "loaded": args.loaded}))
    con.result(f"Run folder: {run.run_dir} (solve it again with: payload-agent solve {run.run_dir})")
    con.emit_json({"ok": True, "exit_code": 0, "run_dir": str(run.run_dir), "result_file": str(path), "result": result})
    return 0


def solve_imported(run_dir: Path, manifest: Mapping[str, Any], args, con: Console) -> int:
    """`solve` on a folder written by `import`: the same analysis from the folder's own copies."""
    import time

    from payload_agent.recording.imported_run import open_imported_run, write_result

    if getattr(args, "baseline", None) or getattr(args, "solver", None) or getattr(args, "history", False):
        raise ConfigError("solve", "--baseline, --solver and --history do not apply to an imported recording")
    run = open_imported_run(run_dir, manifest)
    if getattr(args, "robot", None):
        kin = load_robot(args).robot.kinematics
    else:
        kin = _kinematics(manifest["config"], str(run_dir / "manifest.json"))
    result = _analyse(run, kin).to_json()
    name = Path(args.result) if getattr(args, "result", None) else None
    if name is not None and name.exists():
        raise ConfigError("--result", f"{name} exists; results are never overwritten")
    path = write_result(name.parent if name else run_dir, result,
                        name.name if name else f"result-solve-{time.strftime('%Y%m%d-%H%M%S')}.json")
    sources = {r: manifest["recordings"][r]["source"] for r in ("empty", "loaded")}
    con.say(describe(result, sources))
    con.result(f"Result written to {path} (the run's own result.json is unchanged)")
    con.emit_json({"ok": True, "exit_code": 0, "result_file": str(path), "result": result})
    return 0
