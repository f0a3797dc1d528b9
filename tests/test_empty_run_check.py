"""The empty run is segmented right after it is recorded, before the tool is mounted (issue 19).

A sweep of the empty run is broken on purpose (its recorded angles frozen, as a stuck encoder value
would leave them: no constant-speed window can be found). The session must find that before the
simulated tool change, redo that sweep within --retry-sweeps, and then identify the payload it was
not told, from the redone sweep."""

from __future__ import annotations

import numpy as np
import pytest

from payload_agent.configuration.config import parse_config
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.rundata import load_manifest
from payload_agent.session.runner import RunOptions, run_identification

from conftest import tweak

pytest.importorskip("mujoco")

BROKEN = "b-j2-up"


def test_a_broken_empty_sweep_is_redone_before_the_tool_is_mounted(sim_ec66_data, monkeypatch, tmp_path):
    data = tweak(sim_ec66_data, "robot.name", "empty-check")
    data = tweak(data, "storage", {"state_dir": str(tmp_path / "state"), "runs_dir": str(tmp_path / "runs")})
    data = tweak(data, "simulation.payload", {"mass_kg": 1.7, "cog_mm": [25.0, -15.0, 70.0]})
    config = parse_config(data, "empty-check.yaml")
    frozen: dict[str, object] = {}
    real_sink = RunRecorder.sink

    def sink(self, sample):
        entry = self._entry
        if entry is not None and self._phase == "empty" and entry["name"] == BROKEN and not frozen.get("done"):
            frozen.setdefault("q", sample.q)  # the first attempt of this sweep records one angle throughout
            sample = type(sample)(sample.t_ctrl, sample.t_recv, frozen["q"], sample.effort)
        elif frozen.get("q") is not None:
            frozen["done"] = True
        real_sink(self, sample)

    monkeypatch.setattr(RunRecorder, "sink", sink)
    said: list[str] = []
    outcome = run_identification(config, RunOptions(assume_yes=True, report=False, retry_sweeps=1,
                                                    out=said.append, progress=False))
    redo = next(i for i, line in enumerate(said) if "cannot be segmented; redoing before the tool is mounted" in line)
    mount = next(i for i, line in enumerate(said) if "tool mounted" in line)
    assert BROKEN in said[redo] and redo < mount
    manifest = load_manifest(outcome.run_dir)
    empty = manifest["phases"]["empty"]
    assert [e["status"] for e in empty["sweeps"] if e["name"] == BROKEN] == ["complete"]
    assert [r["name"] for r in empty["redone"]] == [BROKEN]
    assert (outcome.run_dir / empty["redone"][0]["file"]).exists()  # the broken attempt's data is kept
    est = outcome.result.primary
    assert abs(est.mass_kg - 1.7) < 0.05
    assert np.max(np.abs(np.asarray(est.cog_mm) - [25.0, -15.0, 70.0])) < 5.0
