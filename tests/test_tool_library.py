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
