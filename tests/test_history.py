"""Per-robot identification history (agent/history.py) on a temporary SQLite file."""

from __future__ import annotations

import sqlite3

import pytest

from payload_agent.output.history_table import format_history
from payload_agent.recording import history
from payload_agent.types import PayloadSetting
from payload_agent.errors import DataError
from payload_agent.recording.history import HistoryEntry


def entry(mass=2.0, cog=(40.0, -25.0, 70.0), std=0.001, cog_std=(0.2, 0.2, 0.2), tool=None, t="2026-11-21T08:00:00+00:00",
          **kw) -> HistoryEntry:
    return HistoryEntry(robot="sim-ec66", run_dir=f"runs/{t}", solver="general", mass_kg=mass, cog_mm=cog,
                        mass_std_kg=std, cog_std_mm=cog_std, tool=tool, time_utc=t, **kw)


def test_record_creates_versioned_db_and_round_trips(tmp_path):
    db = tmp_path / "state" / "sim-ec66" / "history.sqlite"
    e = entry(tool="gripper-A", quality_passed=False, quality_reasons=["pose b and d disagree"],
              baseline_run_dir="runs/base", baseline_fingerprint="abc", gains_note="calibrated 2026-11-01",
              config_fingerprint="0123456789abcdef")
    new_id = history.record(db, e)
    assert new_id == e.id == 1 and db.exists()
    with sqlite3.connect(db) as conn:
        assert conn.execute("PRAGMA user_version").fetchone()[0] == history.SCHEMA_VERSION
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    [back] = history.entries(db)
    assert back == e  # every field survives, including the JSON reasons and tuples
    assert back.mass_ci95_kg == pytest.approx(1.96 * 0.001)
    assert back.cog_ci95_mm == pytest.approx((1.96 * 0.2,) * 3)


def test_entries_filter_order_limit_and_missing_db(tmp_path):
    db = tmp_path / "h.sqlite"
    assert history.entries(db) == [] and not db.exists()  # reading never creates the file
    history.record(db, entry(tool="A", t="2026-11-21T08:00:00+00:00"))
    history.record(db, entry(tool=None, t="2026-11-21T07:00:00+00:00"))  # recorded later, happened earlier
    history.record(db, entry(tool="A", t="2026-11-21T09:00:00+00:00", mass=2.5))
    assert [e.time_utc[11:13] for e in history.entries(db)] == ["07", "08", "09"]
    assert [e.mass_kg for e in history.entries(db, tool="A")] == [2.0, 2.5]
    assert [e.time_utc[11:13] for e in history.entries(db, limit=2)] == ["08", "09"]  # the most recent, oldest first
    assert history.entries(db, robot="other") == []


def test_mark_applied_stores_readback(tmp_path):
    db = tmp_path / "h.sqlite"
    i = history.record(db, entry())
    history.mark_applied(db, i, PayloadSetting(2.0001, (0.04, -0.025, 0.07), tool_num=3), time_utc="2026-11-21T08:01:00+00:00")
    [e] = history.entries(db)
    assert e.applied and e.applied_utc == "2026-11-21T08:01:00+00:00" and e.applied_tool_num == 3
    assert e.applied_mass_kg == pytest.approx(2.0001)
    assert e.applied_cog_mm == pytest.approx((40.0, -25.0, 70.0))
    with pytest.raises(DataError, match="no history entry #99"):
        history.mark_applied(db, 99, PayloadSetting(1.0, (0, 0, 0)))


def test_from_result_json_reads_runresult_keys(tmp_path):
    result = {"robot": "sim-ec66", "run_dir": "runs/x", "solver": "general", "mass_kg": 2.01,
              "cog_mm": [39.6, -24.7, 69.1], "mass_std_kg": 0.0007, "cog_std_mm": [0.16, 0.18, 0.22],
              "quality": {"passed": True, "reasons": []}}
    e = HistoryEntry.from_result_json(result, tool="gripper-A", config_fingerprint="ff")
    assert (e.mass_kg, e.cog_mm, e.mass_std_kg, e.cog_std_mm) == (2.01, (39.6, -24.7, 69.1), 0.0007, (0.16, 0.18, 0.22))
    assert e.quality_passed is True and e.tool == "gripper-A" and e.config_fingerprint == "ff"
    three_step = {k: v for k, v in result.items() if k not in ("mass_std_kg", "cog_std_mm", "quality")}
    e2 = HistoryEntry.from_result_json(three_step)
    assert e2.mass_std_kg is None and e2.cog_std_mm is None and e2.quality_passed is None
    with pytest.raises(DataError, match="mass_kg"):
        HistoryEntry.from_result_json({"robot": "r", "run_dir": "d", "solver": "general", "cog_mm": [0, 0, 0]})


def test_compare_flags_only_significant_changes_within_the_same_tool(tmp_path):
    db = tmp_path / "h.sqlite"
    # combined 95 % limit for mass: 1.96·sqrt(2)·0.001 = 0.00277 kg; for cog: 1.96·sqrt(2)·0.2 = 0.554 mm
    history.record(db, entry(tool="A", t="2026-11-21T01:00:00+00:00"))
    history.record(db, entry(tool="A", t="2026-11-21T02:00:00+00:00", mass=2.002))  # within: no flag
    history.record(db, entry(tool="B", t="2026-11-21T03:00:00+00:00", mass=5.0))  # first of tool B: no flag
    history.record(db, entry(tool="A", t="2026-11-21T04:00:00+00:00", mass=2.010, cog=(40.0, -25.0, 71.0)))
    history.record(db, entry(tool=None, t="2026-11-21T05:00:00+00:00", mass=3.0))  # first unlabeled: no flag
    history.record(db, entry(tool=None, t="2026-11-21T06:00:00+00:00", mass=3.0, cog=(41.0, -25.0, 70.0)))
    history.record(db, entry(tool="A", t="2026-11-21T07:00:00+00:00", mass=2.0, std=None, cog_std=None))  # no σ
    all_entries = history.entries(db)
    flags = history.compare_to_previous(all_entries)
    assert [(f.entry_id, f.previous_id, f.quantities) for f in flags] == [(4, 2, ("mass", "cog z")), (6, 5, ("cog x",))]
    f = flags[0]
    assert f.mass_delta_kg == pytest.approx(0.008) and f.mass_limit_kg == pytest.approx(1.96 * 2 ** 0.5 * 0.001)
    assert "#4 differs from #2 (tool 'A')" in f.describe() and "mass +0.0080 kg" in f.describe()
    assert history.flag_for(db, 4) == f and history.flag_for(db, 2) is None


def test_format_history_table(tmp_path):
    db = tmp_path / "h.sqlite"
    history.record(db, entry(tool="gripper-A", t="2026-11-21T01:00:00+00:00", quality_passed=True))
    i = history.record(db, entry(tool="gripper-A", t="2026-11-21T02:00:00+00:00", mass=2.1, quality_passed=False))
    history.mark_applied(db, i, PayloadSetting(2.1, (0.04, -0.025, 0.07)))
    all_entries = history.entries(db)
    text = format_history(all_entries, history.compare_to_previous(all_entries))
    lines = text.splitlines()
    assert lines[0].split()[:3] == ["id", "time", "(UTC)"]
    row2 = next(line for line in lines if line.startswith("2 "))
    assert "gripper-A" in row2 and "2.100 ± 0.002" in row2 and "FAILED" in row2 and "yes" in row2 and "! mass" in row2
    assert "2026-11-21 02:00" in row2
    assert "run folder" in lines[0] and "2026-11-21T02:00:00+00:00" in row2  # the run's name: solve/report take it
    assert "#2 differs from #1" in text
    only_last = format_history(all_entries, history.compare_to_previous(all_entries), last=1)
    assert not any(line.startswith("1 ") for line in only_last.splitlines())
    assert format_history([], []) == "No identifications in the history yet."


def test_refuses_newer_schema_and_foreign_files(tmp_path):
    db = tmp_path / "h.sqlite"
    with sqlite3.connect(db) as conn:
        conn.execute(f"PRAGMA user_version = {history.SCHEMA_VERSION + 1}")
    with pytest.raises(DataError, match="newer payload-agent"):
        history.record(db, entry())
    with pytest.raises(DataError, match="newer payload-agent"):
        history.entries(db)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(DataError, match="not a usable history database"):
        history.record(junk, entry())


def test_entry_json_is_plain_json_with_the_intervals(tmp_path):
    import json

    db = tmp_path / "h.sqlite"
    i = history.record(db, entry(tool="A"))
    history.mark_applied(db, i, PayloadSetting(2.0, (0.04, -0.025, 0.07)))
    [e] = history.entries(db)
    d = json.loads(json.dumps(history.entry_json(e)))  # `history --json` prints exactly this
    assert d["id"] == i and d["tool"] == "A" and d["applied"] is True
    assert d["mass_ci95_kg"] == pytest.approx(1.96 * 0.001) and d["cog_ci95_mm"] == pytest.approx([1.96 * 0.2] * 3)
    assert d["applied_cog_mm"] == pytest.approx([40.0, -25.0, 70.0])
