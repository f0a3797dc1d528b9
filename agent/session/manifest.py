"""The run manifest: what a run folder says about itself (docs/run-format.md describes every key).

The manifest is written when the run folder is created and rewritten after every sweep, so an
aborted run still says what it holds, why it stopped and whether the stop was acknowledged.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from payload_agent.version import __version__
from payload_agent.configuration.config import Config, config_snapshot
from payload_agent.motion.planner import Plan
from payload_agent.types import PayloadSetting

RUN_FORMAT = "payload-agent-run/1"


@dataclass(frozen=True)
class RunManifest:
    """The keys every run manifest starts with (phases, sweeps and results are added as the run goes)."""

    config: Config
    plan: Plan
    mode: str  # identify | baseline | calibrate
    controller: dict[str, str]
    effort_unit: str
    tool: str | None = None
    baseline: dict[str, Any] | None = None
    reference: PayloadSetting | None = None
    simulation_truth: dict[str, Any] | None = None
    kinematic_check: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        c = self.config
        return {
            "format": RUN_FORMAT, "software_version": __version__, "robot": c.robot.name,
            "mode": self.mode, "tool": self.tool, "status": "recording",
            "config_source": c.source, "config": config_snapshot(c),
            "controller": self.controller, "effort_unit": self.effort_unit,
            "gains_nm_per_unit": list(c.effort.gains_nm_per_unit),
            "procedure": self.plan.procedure.name, "plan_fingerprint": self.plan.fingerprint(),
            "plan": [m.to_json() for m in self.plan.moves],
            "baseline": self.baseline,
            "reference_payload": None if self.reference is None else {
                "mass_kg": self.reference.mass_kg, "cog_mm": [1000 * v for v in self.reference.cog_m]},
            "simulation_truth": self.simulation_truth,
            "kinematic_check": self.kinematic_check,
        }


def new_run_dir(config: Config, mode: str, stamp: str) -> Path:
    """A fresh run folder name under the runs directory (never an existing one)."""
    suffix = {"identify": "", "baseline": "-baseline", "calibrate": "-calibration"}[mode]
    run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}{suffix}"
    n = 1
    while run_dir.exists():
        n += 1
        run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}{suffix}-{n}"
    return run_dir

