"""`payload-agent import`: the payload from two recordings of a motion the agent did not make.

The recordings are synthetic UR logs in the RTDE layouts (tests/recorded_motion_data.py): the
payload, the drives' constants and the arm's own torque are set there and the importer is not
told them; only the controller's signals reach it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import recorded_motion_data as data
from payload_agent import cli
from payload_agent.errors import DataError
from payload_agent.evaluation.recorded_motion import analyse_recorded_motion
from payload_agent.recording.motion_csv import parse_column_map, read_motion_csv

SAMPLE = Path(__file__).parent / "data" / "rtde_31col_sample.csv"


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    return data.pair(tmp_path_factory.mktemp("recorded"), rubbish_rows=3)


def test_the_shipped_sample_reads_with_the_column_map_and_its_rubbish_rows_are_named():
    rec = read_motion_csv(SAMPLE, data.COLUMNS)
    assert rec.rows == 40 and rec.q.shape == (40, 6) and rec.effort_unit == "A"
    assert len(rec.dropped) == 2 and rec.dropped[0].startswith("line 1: 2 values where the columns need 31")
    assert rec.target_moment_nm is not None and rec.qd is not None
    assert np.all(np.diff(rec.t) > 0)


def test_a_header_names_the_columns_and_gives_the_same_recording(tmp_path, pair):
    rows = np.loadtxt(pair[1], delimiter=",")
    with_header = data.write(tmp_path / "header.csv", rows, header=True)
    spaced = tmp_path / "spaced.txt"  # UR's RTDE client example writes space-separated columns
    spaced.write_text(with_header.read_text().replace(",", " "))
    a, b, c = read_motion_csv(pair[1], data.COLUMNS), read_motion_csv(with_header), read_motion_csv(spaced)
    for other in (b, c):
        np.testing.assert_array_equal(a.q, other.q)
        np.testing.assert_array_equal(a.current_a, other.current_a)
    with pytest.raises(DataError, match="has a header line"):
        read_motion_csv(with_header, data.COLUMNS)


@pytest.mark.parametrize("edit, message", [
    (lambda lines: lines, "no header line and no column map"),
    (lambda lines: lines[:200] + ["1,2,3"] + lines[200:], "line 201: 3 values where the columns need 31"),
    (lambda lines: ["1,2"] * 60 + lines, "the first 51 rows are not readings"),
])
def test_bad_recordings_are_refused_naming_the_line(tmp_path, pair, edit, message):
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(edit(pair[1].read_text().splitlines())) + "\n")
    with pytest.raises(DataError, match=message):
        read_motion_csv(bad, None if "column map" in message else data.COLUMNS)


def test_column_maps_are_checked():
    assert parse_column_map("timestamp,actual_q[2],-") == ["timestamp", "actual_q_0", "actual_q_1", "-"]
    with pytest.raises(DataError, match="'q\\[x\\]' is not a column name"):
        parse_column_map("timestamp,q[x]")
    with pytest.raises(DataError, match="actual_current_5 missing"):
        read_motion_csv(SAMPLE, "timestamp,actual_q[6],actual_qd[6],actual_current[5],-,target_current[6],"
                                "target_moment[6]")


def test_the_payload_and_the_drives_constants_come_out_of_the_controllers_signals(pair):
    empty, loaded = read_motion_csv(pair[0], data.COLUMNS), read_motion_csv(pair[1], data.COLUMNS)
    result = analyse_recorded_motion(empty, loaded, data.UR10E)
    r = result.to_json()
    assert r["torque_constants"]["determined"] == [True] * 6
    np.testing.assert_allclose(r["torque_constants"]["k_nm_per_a"], data.K_TRUE, rtol=0.005)
    assert abs(r["alignment"]["shift_s"] + 0.7) < 0.005 and r["alignment"]["angle_rms_mrad"] < 0.1
    assert abs(r["mass_kg"] - data.MASS) < max(3 * r["mass_std_kg"], 0.01 * data.MASS)
    assert r["mass_std_kg"] < 0.03 * data.MASS
    err = np.asarray(r["cog_mm"]) - 1000 * data.COG_M
    assert np.all(np.abs(err) < 3 * np.asarray(r["cog_std_mm"]) + 1.0), (err, r["cog_std_mm"])
    # this slow excitation hardly accelerates the tool: the inertia is refused, not guessed
    assert r["inertia_com_kgm2"] is None and r["inertia_unsupported"]["reason"]
    assert any("no inertia given" in n for n in r["notes"])


def test_two_different_motions_are_refused(tmp_path, pair):
    rows = np.loadtxt(pair[1], delimiter=",")
    rows[:, 1:7] = rows[::-1, 1:7]  # the same poses run backwards: another motion
    other = data.write(tmp_path / "other.csv", rows, header=False)
    with pytest.raises(DataError, match="do not record the same motion"):
        analyse_recorded_motion(read_motion_csv(pair[0], data.COLUMNS), read_motion_csv(other, data.COLUMNS), data.UR10E)


def test_import_writes_a_run_folder_that_solve_repeats_to_the_digit(tmp_path, pair, capsys, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    args = ["import", "--robot", "ur10e", "--empty", str(pair[0]), "--loaded", str(pair[1]), "--columns", data.COLUMNS]
    assert cli.main(args + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    run_dir = Path(out["run_dir"])
    assert sorted(p.name for p in (run_dir / "recorded").iterdir()) == ["empty.csv", "loaded.csv"]
    assert (run_dir / "recorded" / "loaded.csv").read_bytes() == pair[1].read_bytes()
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["kind"] == "recorded-motion" and manifest["column_map"] == data.COLUMNS
    assert cli.main(["solve", str(run_dir), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    for key in ("mass_kg", "mass_std_kg", "cog_mm", "theta_si", "gains_nm_per_unit"):
        assert again["result"][key] == out["result"][key], key
    copy = run_dir / "recorded" / "empty.csv"
    copy.write_text(copy.read_text().replace("0.", "1.", 1))
    assert cli.main(["solve", str(run_dir)]) == DataError.exit_code
    assert "changed since it was imported" in capsys.readouterr().err


def test_import_refuses_a_missing_file_and_needs_gains_where_the_controller_gives_none(tmp_path, pair, capsys,
                                                                                       monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    assert cli.main(["import", "--robot", "ur10e", "--empty", str(tmp_path / "nope.csv"), "--loaded", str(pair[1]),
                     "--columns", data.COLUMNS]) == 2
    assert "--empty" in capsys.readouterr().err
    no_targets = "timestamp,actual_q[6],actual_qd[6],actual_current[6],-,-,-,-,-,-,-,-,-,-,-,-"
    assert cli.main(["import", "--robot", "ur10e", "--empty", str(pair[0]), "--loaded", str(pair[1]),
                     "--columns", no_targets]) == DataError.exit_code
    assert "--gains config" in capsys.readouterr().err
    assert cli.main(["import", "--robot", "ur10e", "--empty", str(pair[0]), "--loaded", str(pair[1]),
                     "--columns", no_targets, "--gains", "config", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["result"]["gain_source"].startswith("robot YAML effort.gains_nm_per_unit")
