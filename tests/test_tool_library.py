"""The tool library (agent/tools): stored entries, history, numbers, JSON export/import and `payload-agent tools`."""

from __future__ import annotations

import json

import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.cli import main
from payload_agent.errors import DataError
from payload_agent.tools import library, transfer
from payload_agent.tools.library import ToolEntry

ROBOT = "cell-1"


def entry(name="gripper-A", mass=2.0, cog=(40.0, -25.0, 70.0), **kw):
    return ToolEntry(name, mass, cog, mass_std_kg=0.002, cog_std_mm=(0.5, 0.6, 0.7), **kw)


def test_store_get_history_and_remove(tmp_path):
    db = tmp_path / "tools.sqlite"
    assert library.list_tools(db, ROBOT) == [] and not db.exists()  # reading never creates it
    library.store(db, ROBOT, entry(run_dir="runs/a", number=3))
    library.store(db, ROBOT, entry(mass=2.1, run_dir="runs/b"))  # re-identified: keeps its number
    library.store(db, ROBOT, entry("screwdriver", 1.2, (0, 0, 120)))
    got = library.require(db, ROBOT, "gripper-A")
    assert got.mass_kg == 2.1 and got.run_dir == "runs/b" and got.number == 3 and got.inertia_com_kgm2 is None
    assert library.by_number(db, ROBOT, 3).name == "gripper-A"
    assert [t.name for t in library.list_tools(db, ROBOT)] == ["gripper-A", "screwdriver"]
    assert library.list_tools(db, "other-robot") == []
    library.remove(db, ROBOT, "gripper-A")
    assert library.get(db, ROBOT, "gripper-A") is None
    hist = library.versions(db, ROBOT, "gripper-A")
    assert [v.action for v in hist] == ["stored", "stored", "removed"]
    assert [v.entry.mass_kg for v in hist] == [2.0, 2.1, 2.1]
    with pytest.raises(DataError, match="no tool 'gripper-A'.*known: screwdriver"):
        library.require(db, ROBOT, "gripper-A")


def test_refuses_bad_values_naming_the_field(tmp_path):
    db = tmp_path / "tools.sqlite"
    with pytest.raises(DataError, match="mass_kg"):
        library.store(db, ROBOT, entry(mass=-1.0))
    with pytest.raises(DataError, match="tool name"):
        library.store(db, ROBOT, entry(name="../etc"))
    with pytest.raises(DataError, match="inertia_com_kgm2"):
        library.store(db, ROBOT, entry(inertia_com_kgm2=(1.0, 2.0)))
    library.store(db, ROBOT, entry(number=7))
    with pytest.raises(DataError, match="number 7 already belongs to tool 'gripper-A'"):
        library.store(db, ROBOT, entry("other", number=7))


def test_inertia_fields_are_kept(tmp_path):
    db = tmp_path / "tools.sqlite"
    inertia = (0.01, 0.02, 0.03, 0.0, 0.001, 0.0)
    library.store(db, ROBOT, entry(inertia_com_kgm2=inertia, inertia_com_std_kgm2=(1e-4,) * 6))
    assert library.require(db, ROBOT, "gripper-A").inertia_com_kgm2 == inertia
    stored = library.store_result(db, ROBOT, "from-result", {"mass_kg": 1.5, "cog_mm": [1, 2, 3], "run_dir": "r",
                                                             "inertia_com_kgm2": [[1, 0, 0], [0, 2, 0], [0, 0, 3]]}, 4)
    assert stored.inertia_com_kgm2 == (1, 2, 3, 0, 0, 0) and stored.history_id == 4


def test_export_import_round_trip_and_errors(tmp_path):
    a, b = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    library.store(a, ROBOT, entry(number=1))
    library.store(a, ROBOT, entry("vacuum", 0.8, (0, 10, 60)))
    path = tmp_path / "tools.json"
    path.write_text(json.dumps(transfer.export_document(a, ROBOT)))
    stored, skipped = transfer.import_file(b, "cell-2", path)
    assert sorted(e.name for e in stored) == ["gripper-A", "vacuum"] and skipped == []
    got = library.require(b, "cell-2", "gripper-A")
    assert got.source == "imported" and got.number == 1 and "cell-1" in got.note and got.cog_mm == (40, -25, 70)
    stored, skipped = transfer.import_file(b, "cell-2", path)
    assert stored == [] and sorted(skipped) == ["gripper-A", "vacuum"]
    doc = json.loads(path.read_text())
    doc["tools"][1]["cog_mm"] = [1, 2]
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match=r"tools\[1\].cog_mm: expected a list of 3 numbers"):
        transfer.import_file(tmp_path / "c.sqlite", ROBOT, path)
    assert not (tmp_path / "c.sqlite").exists()  # checked whole before anything is stored
    path.write_text("{not json")
    with pytest.raises(DataError, match="not a JSON tool library export"):
        transfer.import_file(b, ROBOT, path)


def test_cli_tools_commands(tmp_path, capsys):
    data = tweak(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), "storage.state_dir",
                 str(tmp_path / "state"))
    cfg = tmp_path / "robot.yaml"
    cfg.write_text(yaml.safe_dump(data))
    db = tmp_path / "state" / "sim-ec66" / "tools.sqlite"
    library.store(db, "sim-ec66", entry(run_dir="runs/x"))
    assert main(["tools", "--robot", str(cfg), "list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [t["name"] for t in listed["tools"]] == ["gripper-A"]
    assert main(["tools", "--robot", str(cfg), "show", "gripper-A"]) == 0
    out = capsys.readouterr()
    assert "2.0000 kg" in out.out and "stored" in out.out + out.err
    export = tmp_path / "export.json"
    assert main(["tools", "--robot", str(cfg), "export", str(export)]) == 0
    assert main(["tools", "--robot", str(cfg), "remove", "gripper-A"]) == 0
    assert main(["tools", "--robot", str(cfg), "show", "gripper-A"]) == 5  # DataError: exit 5, no traceback
    assert "no tool 'gripper-A'" in capsys.readouterr().err
    assert main(["tools", "--robot", str(cfg), "import", str(export)]) == 0
    assert library.require(db, "sim-ec66", "gripper-A").source == "imported"
    with pytest.raises(SystemExit) as exc:  # refused by the parser before any session starts
        main(["run", "--robot", str(cfg), "--tool", "bad/name"])
    assert exc.value.code == 2


V1_COLUMNS = """
    mass_kg REAL NOT NULL, cog_x_mm REAL NOT NULL, cog_y_mm REAL NOT NULL, cog_z_mm REAL NOT NULL,
    mass_std_kg REAL, cog_std_x_mm REAL, cog_std_y_mm REAL, cog_std_z_mm REAL,
    inertia_com_kgm2 TEXT, inertia_com_std_kgm2 TEXT, number INTEGER,
    run_dir TEXT, history_id INTEGER, source TEXT NOT NULL, time_utc TEXT NOT NULL, note TEXT"""
V1_NAMES = [c.split()[0] for c in V1_COLUMNS.split(",")]


def _v1_library(db):
    """A tool library as payload-agent wrote it before schema version 2 (σ only, no covariance column)."""
    import sqlite3

    conn = sqlite3.connect(db)
    conn.executescript(f"""
        CREATE TABLE tools (robot TEXT NOT NULL, name TEXT NOT NULL, {V1_COLUMNS}, PRIMARY KEY (robot, name));
        CREATE UNIQUE INDEX tools_number ON tools (robot, number) WHERE number IS NOT NULL;
        CREATE TABLE tool_versions (id INTEGER PRIMARY KEY AUTOINCREMENT, robot TEXT NOT NULL, name TEXT NOT NULL,
                                    action TEXT NOT NULL, {V1_COLUMNS});
        CREATE INDEX tool_versions_name ON tool_versions (robot, name, id);
        PRAGMA user_version = 1;""")
    row = (ROBOT, "old-gripper", 1.5, 10.0, 20.0, 30.0, 0.003, 0.4, 0.5, 0.6, "[0.01, 0.02, 0.03, 0, 0, 0]", None, 4,
           "runs/old", 9, "identified", "2026-01-01T00:00:00+00:00", None)
    marks = ", ".join("?" for _ in row)
    conn.execute(f"INSERT INTO tools VALUES ({marks})", row)
    conn.execute("INSERT INTO tool_versions (robot, name, action, mass_kg, cog_x_mm, cog_y_mm, cog_z_mm, source, "
                 "time_utc) VALUES (?, ?, 'stored', 1.4, 10, 20, 30, 'identified', '2025-12-01T00:00:00+00:00')",
                 (ROBOT, "old-gripper"))
    conn.execute(f"INSERT INTO tool_versions (robot, name, action, {', '.join(V1_NAMES)}) "
                 f"VALUES (?, ?, 'stored', {', '.join('?' for _ in row[2:])})", (ROBOT, "old-gripper", *row[2:]))
    conn.commit()
    conn.close()


COV = ((4e-6, 1e-7, -2e-7, 3e-7), (1e-7, 9e-8, 0.0, 1e-8), (-2e-7, 0.0, 8e-8, 0.0), (3e-7, 1e-8, 0.0, 1.2e-7))


def test_a_version_1_library_is_upgraded_in_place(tmp_path):
    """Schema v1 -> v2: the first read adds the covariance column to both tables, keeps every row and the history,
    and the file then takes entries with a covariance; a file of a newer version is refused, not rewritten."""
    import sqlite3

    db = tmp_path / "tools.sqlite"
    _v1_library(db)
    old = library.require(db, ROBOT, "old-gripper")  # a read upgrades it
    assert old.mass_kg == 1.5 and old.number == 4 and old.covariance_theta_si is None
    assert old.inertia_com_kgm2 == (0.01, 0.02, 0.03, 0, 0, 0)
    with sqlite3.connect(db) as conn:
        assert conn.execute("PRAGMA user_version").fetchone()[0] == library.SCHEMA_VERSION == 2
        for table in ("tools", "tool_versions"):
            assert "covariance_theta_si" in [r[1] for r in conn.execute(f"PRAGMA table_info({table})")]
    assert [v.entry.mass_kg for v in library.versions(db, ROBOT, "old-gripper")] == [1.4, 1.5]
    library.store(db, ROBOT, entry("old-gripper", 1.6, covariance_theta_si=COV))
    got = library.require(db, ROBOT, "old-gripper")
    assert got.covariance_theta_si == COV and got.number == 4  # the number carried over from the v1 row
    assert [v.entry.covariance_theta_si for v in library.versions(db, ROBOT, "old-gripper")] == [None, None, COV]
    other = tmp_path / "other.sqlite"
    _v1_library(other)
    with sqlite3.connect(other) as conn:
        conn.execute("PRAGMA user_version = 3")
    with pytest.raises(DataError, match="newer payload-agent"):
        library.list_tools(other, ROBOT)


def test_covariance_and_inertia_stored_exported_and_shown(tmp_path, capsys):
    """The run's covariance of θ (its [m, m·c] block) and inertia are stored, survive export/import (format 2; a
    format-1 export still imports), bad matrices are refused naming the key, and `tools show` prints the inertia
    as tensor and principal moments with their axes."""
    import math

    import numpy as np

    db = tmp_path / "tools.sqlite"
    big = np.zeros((5, 5))
    big[:4, :4] = COV
    big[4, 4] = 7.0  # a fit with more parameters: only the [m, m·c] block is the tool's
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    tensor = R @ np.diag([0.004, 0.006, 0.002]) @ R.T
    stored = library.store_result(db, ROBOT, "rotated", {
        "mass_kg": 2.0, "cog_mm": [40, -25, 70], "mass_std_kg": 0.002, "cog_std_mm": [0.5, 0.6, 0.7], "run_dir": "r",
        "covariance_theta_si": big.tolist(), "inertia_com_kgm2": tensor.tolist(),
        "inertia_com_std_kgm2": (np.full((3, 3), 1e-5)).tolist()}, 3)
    assert stored.covariance_theta_si == COV
    moments, abc = library.require(db, ROBOT, "rotated").principal_inertia()
    assert sorted(moments) == pytest.approx([0.002, 0.004, 0.006])
    assert moments[0] == pytest.approx(0.004) and abc == pytest.approx((30.0, 0.0, 0.0), abs=1e-6)
    path = tmp_path / "tools.json"
    path.write_text(json.dumps(transfer.export_document(db, ROBOT)))
    doc = json.loads(path.read_text())
    assert doc["format"] == "payload-agent-tools/2"
    stored, _ = transfer.import_file(tmp_path / "b.sqlite", ROBOT, path)
    assert stored[0].covariance_theta_si == COV and stored[0].inertia_com_kgm2 == pytest.approx(
        [tensor[0, 0], tensor[1, 1], tensor[2, 2], tensor[0, 1], tensor[0, 2], tensor[1, 2]])
    for bad, why in (([[1, 0], [0, 1]], "4 rows of 4 numbers"), ([[1, 2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                [0, 0, 0, 1]], "not symmetric"),
                     ([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not positive semi-definite")):
        doc["tools"][0]["covariance_theta_si"] = bad
        path.write_text(json.dumps(doc))
        with pytest.raises(DataError, match=r"tools\[0\].covariance_theta_si: .*" + why):
            transfer.import_file(tmp_path / "c.sqlite", ROBOT, path)
    doc["format"] = "payload-agent-tools/1"
    del doc["tools"][0]["covariance_theta_si"]
    path.write_text(json.dumps(doc))
    stored, _ = transfer.import_file(tmp_path / "d.sqlite", ROBOT, path)
    assert stored[0].covariance_theta_si is None
    # `tools show`
    data = tweak(yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text()), "storage.state_dir",
                 str(tmp_path / "state"))
    cfg = tmp_path / "robot.yaml"
    cfg.write_text(yaml.safe_dump(data))
    sim_db = tmp_path / "state" / "sim-ec66" / "tools.sqlite"
    library.store(sim_db, "sim-ec66", library.require(db, ROBOT, "rotated"))
    library.store(sim_db, "sim-ec66", entry("plain"))
    assert main(["tools", "--robot", str(cfg), "show", "rotated"]) == 0
    out = capsys.readouterr().out
    assert "principal moments JX, JY, JZ kg·m²: 0.00400, 0.00600, 0.00200" in out
    assert "axes A, B, C (z-y'-x'' from the flange axes): 30.0, " in out and "covariance of [m, m·cx, m·cy, m·cz]" in out
    assert main(["tools", "--robot", str(cfg), "show", "plain"]) == 0
    assert "inertia: not identified" in capsys.readouterr().out
