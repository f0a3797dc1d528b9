"""A run folder written from docs/run-format.md alone (reordered and extra CSV columns, only the required
manifest keys) is solved by `payload-agent solve`, from the folder alone, into a new result file."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT
from payload_agent import cli
from payload_agent.configuration.config import parse_config
from payload_agent.motion.planner import make_plan
from payload_agent.recording import rundata

SCHEMA = json.loads((ROOT / "docs" / "run-manifest.schema.json").read_text())
TRUTH_KG, TRUTH_COG_MM = 2.0, (40.0, -25.0, 70.0)
ARM = np.array([6.0, 1.2, 0.4, 0.6])  # the arm's own "gravity" θ, the same in both phases
GAIN = 2.0  # N·m per A: the CSVs hold amperes; only the manifest's gains make them N·m
DT = 0.03


# -- a minimal JSON Schema checker (the subset docs/run-manifest.schema.json uses) --------------------
def validate(value, schema, path="$", root=SCHEMA) -> list[str]:
    if "$ref" in schema:
        return validate(value, root["$defs"][schema["$ref"].split("/")[-1]], path, root)
    errs: list[str] = []
    types = schema.get("type")
    if types is not None:
        names = [types] if isinstance(types, str) else types
        ok = {"object": isinstance(value, dict), "array": isinstance(value, list), "string": isinstance(value, str),
              "null": value is None, "boolean": isinstance(value, bool),
              "integer": isinstance(value, int) and not isinstance(value, bool),
              "number": isinstance(value, (int, float)) and not isinstance(value, bool)}
        if not any(ok[n] for n in names):
            return [f"{path}: {value!r:.40} is not {types}"]
    if "const" in schema and value != schema["const"]:
        errs.append(f"{path}: {value!r} != {schema['const']!r}")
    if "enum" in schema and value not in schema["enum"]:
        errs.append(f"{path}: {value!r} not in {schema['enum']}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            errs.append(f"{path}: {value} < {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            errs.append(f"{path}: {value} > {schema['maximum']}")
        if "exclusiveMinimum" in schema and value <= schema["exclusiveMinimum"]:
            errs.append(f"{path}: {value} <= {schema['exclusiveMinimum']}")
    if isinstance(value, str) and len(value) < schema.get("minLength", 0):
        errs.append(f"{path}: too short")
    if isinstance(value, dict):
        errs += [f"{path}.{k}: required" for k in schema.get("required", []) if k not in value]
        for k, sub in schema.get("properties", {}).items():
            if k in value:
                errs += validate(value[k], sub, f"{path}.{k}", root)
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0) or len(value) > schema.get("maxItems", 1 << 30):
            errs.append(f"{path}: {len(value)} items")
        if "items" in schema:
            for i, item in enumerate(value):
                errs += validate(item, schema["items"], f"{path}[{i}]", root)
    return errs


# -- a run folder as an outside tool writes it ------------------------------------------------------
def _profile(q0, q1, v, a):
    d = float(np.max(np.abs(q1 - q0)))
    if d < v * v / a:
        v = math.sqrt(d * a)
    t_acc, dur = v / a, d / v + v / a
    t = np.arange(0.0, dur + DT, DT)
    s = np.where(t < t_acc, 0.5 * a * t ** 2, np.where(t < dur - t_acc, 0.5 * a * t_acc ** 2 + v * (t - t_acc),
                                                       d - 0.5 * a * np.clip(dur - t, 0, None) ** 2))
    return np.vstack([[q0] * 8, q0 + (np.clip(s, 0, d) / d)[:, None] * (q1 - q0), [q1] * 8])


@pytest.fixture(scope="module")
def robot_data():
    return yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())


def write_foreign_run(run_dir: Path, robot_data: dict, *, gains_in_manifest: bool = True) -> Path:
    """Only what docs/run-format.md requires: the manifest's required keys, a config snapshot with robot
    name and kinematics, CSV columns in another order plus a column payload-agent does not know."""
    cfg = parse_config(robot_data)  # only to know where the shipped procedure goes; the files are hand-written
    kin = cfg.robot.kinematics
    rng = np.random.default_rng(3)
    truth = np.array([TRUTH_KG, *(TRUTH_KG * np.asarray(TRUTH_COG_MM) / 1000.0)])
    columns = ["temperature_c", *[f"effort{j}" for j in range(6, 0, -1)], "t_recv_s",
               *[f"q{j}_rad" for j in range(1, 7)]]  # reordered, extra column first, no t_ctrl_s at all
    phases = {}
    t = 0.0
    for phase, payload in (("empty", np.zeros(4)), ("loaded", truth)):
        (run_dir / phase).mkdir(parents=True)
        sweeps = []
        q = np.radians(robot_data["simulation"]["start_deg"])
        for move in make_plan(cfg).moves:
            path = _profile(q, np.asarray(move.target_rad), move.speed_rad_s, move.accel_rad_s2)
            q = path[-1]
            if move.sweep is None:
                continue
            key = move.sweep
            rel = f"{phase}/{key.pose}_joint{key.joint}_{key.direction}.csv"  # any file name: the manifest says
            with open(run_dir / rel, "w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(columns)
                for qi in path:
                    tau = kin.payload_regressor(qi, range(6)) @ (ARM + payload) + rng.normal(0, 0.05, 6)
                    amps = tau / GAIN
                    row = {"temperature_c": 31.5, "t_recv_s": t, **{f"q{j + 1}_rad": qi[j] for j in range(6)},
                           **{f"effort{j + 1}": amps[j] for j in range(6)}}
                    w.writerow([f"{row[c]:.9g}" for c in columns])
                    t += DT
            sweeps.append({"file": rel, "pose": key.pose, "joint": key.joint, "direction": key.direction,
                           "speed_percent": key.speed_percent, "status": "complete"})
        phases[phase] = {"sweeps": sweeps}
    manifest = {"format": "payload-agent-run/1", "effort_unit": "A", "phases": phases,
                "config": {"robot": {"name": "foreign-ec66",
                                     "kinematics": robot_data["robot"]["kinematics"]}}}
    if gains_in_manifest:
        manifest["gains_nm_per_unit"] = [GAIN] * 6
    (run_dir / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return run_dir


@pytest.fixture(scope="module")
def foreign_run(tmp_path_factory, robot_data):
    return write_foreign_run(tmp_path_factory.mktemp("foreign") / "run1", robot_data)


def _solve(argv, capsys) -> tuple[int, dict]:
    rc = cli.main(["solve", *argv, "--json"])
    out = capsys.readouterr().out
    return rc, json.loads(out)


def test_the_documented_minimum_is_valid_against_the_schema(foreign_run):
    manifest = json.loads((foreign_run / "manifest.json").read_text())
    assert validate(manifest, SCHEMA) == []
    assert tuple(SCHEMA["required"]) == rundata.REQUIRED_MANIFEST_KEYS
    assert tuple(SCHEMA["$defs"]["sweep"]["required"]) == rundata.REQUIRED_SWEEP_KEYS
    for bad in ({k: v for k, v in manifest.items() if k != "phases"}, {**manifest, "format": "x"},
                {**manifest, "effort_unit": "volts"}):
        assert validate(bad, SCHEMA) != []


def test_solve_reads_a_foreign_run_folder_by_column_name(foreign_run, capsys):
    rc, data = _solve([str(foreign_run)], capsys)
    assert rc in (0, 5), data
    result = data["result"]
    assert result["estimates"]["general"]["mass_kg"] == pytest.approx(TRUTH_KG, abs=0.03)
    assert np.allclose(result["estimates"]["general"]["cog_mm"], TRUTH_COG_MM, atol=3.0)
    assert result["solve"]["gains_nm_per_unit"] == [GAIN] * 6 and "effort in A" in result["gains_source"]
    assert result["solve"]["baseline_dir"] is None and result["solve"]["solver"] == "general"
    assert result["samples"] and all(k.endswith("-both") for k in result["samples"])  # up + down: two files, combined
    path = Path(data["result_file"])
    assert path.parent == foreign_run and path.name.startswith("result-solve-") and path.exists()
    assert json.loads(path.read_text())["mass_kg"] == result["mass_kg"]
    assert not (foreign_run / "result.json").exists()  # nothing of the run's own is written
    assert data["ok"] == result["quality"]["passed"] and rc == (0 if data["ok"] else 5)


def test_manifest_gains_are_used(tmp_path, robot_data, capsys):
    no_gains = write_foreign_run(tmp_path / "run", robot_data, gains_in_manifest=False)
    rc, data = _solve([str(no_gains)], capsys)
    assert rc == 5 and "gains_nm_per_unit is missing" in data["error"] and "'A'" in data["error"]
    m = json.loads((no_gains / "manifest.json").read_text())
    m["gains_nm_per_unit"] = [1.0] * 6  # the wrong gain gives half the torque, so half the mass
    (no_gains / "manifest.json").write_text(json.dumps(m))
    rc, data = _solve([str(no_gains)], capsys)
    assert data["result"]["estimates"]["general"]["mass_kg"] == pytest.approx(TRUTH_KG / GAIN, abs=0.03)


def test_solve_never_reads_a_calibration_outside_the_run(foreign_run, capsys, monkeypatch, tmp_path):
    rc, clean = _solve([str(foreign_run)], capsys)
    bogus = {"format": "payload-agent-gains/1", "robot": "foreign-ec66", "effort_unit": "A",
             "gains_nm_per_unit": [GAIN * 1.2] * 6, "fitted_joints": [2, 3], "scale": [1.2] * 6,
             "scale_std": [0.001] * 6, "reference_mass_kg": 3.0, "reference_cog_mm": [0, 0, 80],
             "nominal_fingerprint": "x", "run_dir": "x", "created_utc": "2026-01-01T00:00:00+00:00"}
    for root in (tmp_path / "state", Path(os.environ["XDG_STATE_HOME"]) / "payload-agent"):
        (root / "foreign-ec66").mkdir(parents=True, exist_ok=True)
        (root / "foreign-ec66" / "gains.json").write_text(json.dumps(bogus))
    monkeypatch.chdir(tmp_path)  # ./state/foreign-ec66/gains.json is right here
    rc2, data = _solve([str(foreign_run)], capsys)
    assert data["result"]["mass_kg"] == clean["result"]["mass_kg"]
    assert "calibration" not in data["result"]["gains_source"]


def test_solve_never_overwrites_and_says_which_baseline(foreign_run, tmp_path, capsys):
    target = tmp_path / "mine.json"
    target.write_text("keep me")
    rc, data = _solve([str(foreign_run), "--result", str(target)], capsys)
    assert rc == 2 and "never overwrites" in data["error"] and target.read_text() == "keep me"
    rc, data = _solve([str(foreign_run), "--baseline", str(foreign_run), "--result", str(tmp_path / "b.json")], capsys)
    solved = json.loads((tmp_path / "b.json").read_text())
    assert solved["solve"]["baseline_dir"] == str(foreign_run) and str(foreign_run) in solved["solve"]["baseline"]
    files = sorted(p.name for p in foreign_run.glob("result-solve-*.json"))
    rc, _ = _solve([str(foreign_run)], capsys)
    assert len(sorted(p.name for p in foreign_run.glob("result-solve-*.json"))) == len(files) + 1


def test_solve_errors_name_the_problem(tmp_path, foreign_run, capsys):
    rc, data = _solve([str(tmp_path / "no-such-run")], capsys)
    assert rc == 2 and "no such run folder" in data["error"]
    broken = tmp_path / "broken"
    broken.mkdir()
    m = json.loads((foreign_run / "manifest.json").read_text())
    del m["phases"]["loaded"]["sweeps"][0]["direction"]
    (broken / "manifest.json").write_text(json.dumps(m))
    rc, data = _solve([str(broken)], capsys)
    assert rc == 5 and "phases.loaded.sweeps[0].direction is missing" in data["error"]


def test_csv_columns_by_header(tmp_path):
    p = tmp_path / "s.csv"
    cols = ["effort3", "q1_rad", "t_ctrl_s", "note", *[f"q{j}_rad" for j in range(2, 7)], "effort1", "effort2",
            "effort4", "effort5", "effort6", "t_recv_s"]
    rows = [[3.0, 0.1, "", "hello", 0.2, 0.3, 0.4, 0.5, 0.6, 1.0, 2.0, 4.0, 5.0, 6.0, 10.0],
            [3.5, 0.11, "", "x", 0.2, 0.3, 0.4, 0.5, 0.6, 1.5, 2.5, 4.5, 5.5, 6.5, 10.1]]
    p.write_text(",".join(cols) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n5,0.1")  # torn line
    t, q, effort = rundata.read_sweep_csv(p)
    assert t.tolist() == [10.0, 10.1]  # t_ctrl_s empty: the receive time
    assert q[0].tolist() == [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    assert effort[1].tolist() == [1.5, 2.5, 3.5, 4.5, 5.5, 6.5]
    p.write_text("t_recv_s,q1_rad\n1,2\n")
    with pytest.raises(rundata.DataError, match=r"lacks q2_rad.*effort1"):
        rundata.read_sweep_csv(p)


def test_payload_agents_own_manifest_matches_the_schema(tmp_path, robot_data):
    """The writer and the documentation agree: a manifest as the runner writes it validates."""
    from payload_agent.recording.recorder import RunRecorder
    from payload_agent.session.manifest import RunManifest

    cfg = parse_config(robot_data)
    plan = make_plan(cfg)
    rec = RunRecorder(tmp_path / "run", RunManifest(cfg, plan, "identify", {"vendor": "Elite Robots", "model": "EC66",
                                                                              "firmware": "1", "serial": "2"},
                                                    "percent_rated").to_json())
    rec.begin_phase("loaded")
    rec.begin_sweep(plan.sweeps[0])
    rec.end_sweep("complete")
    rec.end_phase("complete")
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert validate(manifest, SCHEMA) == []
    rundata.check_manifest(manifest, "m")


def test_a_sweep_redone_after_a_stream_gap_keeps_the_earlier_attempt(tmp_path, robot_data):
    """The redo replaces the gap attempt in the phase's list (so the empty-run check sees one complete sweep),
    and the gap attempt's samples stay on disk under the manifest's ``redone`` list."""
    from payload_agent.recording.recorder import RunRecorder
    from payload_agent.types import Sample

    cfg = parse_config(robot_data)
    sweep = make_plan(cfg).sweeps[0]
    rec = RunRecorder(tmp_path / "run", {"format": "payload-agent-run/1", "phases": {}})
    rec.begin_phase("empty")
    for attempt, status in enumerate(("gap", "gap", "complete")):
        rec.begin_sweep(sweep)
        rec.sink(Sample(t_ctrl=float(attempt), t_recv=0.0, q=(0.0,) * 6, effort=(float(attempt),) * 6))
        rec.end_sweep(status, {"gaps": 1} if status == "gap" else None)
    rec.end_phase("complete")
    phase = json.loads((tmp_path / "run" / "manifest.json").read_text())["phases"]["empty"]
    assert [e["status"] for e in phase["sweeps"]] == ["complete"]
    assert [r["file"] for r in phase["redone"]] == [f"empty/{sweep.sweep.name}.csv.incomplete",
                                                    f"empty/{sweep.sweep.name}.csv.incomplete-2"]
    for attempt, r in enumerate(phase["redone"]):
        rows = list(csv.reader((tmp_path / "run" / r["file"]).open()))
        assert float(rows[1][0]) == attempt  # each attempt's own samples, none overwritten
