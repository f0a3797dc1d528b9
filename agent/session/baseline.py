"""The stored empty-flange baseline: what it depends on, whether it still holds, how it is kept.

An identification needs the arm's own effort along the same sweeps without the tool.
Recording it once (`payload-agent baseline`) halves the robot time of every later run,
but only while nothing it depends on has changed: the robot itself, the kinematics
(they decide the joint targets), the procedure and its speeds (friction depends on
speed) and its age (friction drifts with wear and temperature). Every one of those
is stored beside the baseline and checked before it is reused.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from payload_agent.version import __version__
from payload_agent.configuration.config import Config
from payload_agent.types import ControllerInfo
from payload_agent.errors import BaselineError
from payload_agent.motion.planner import Plan
from payload_agent.recording.rundata import load_manifest
from payload_agent.recording.state import RobotState, write_json_atomic

BASELINE_FORMAT = "payload-agent-baseline/1"


def kinematics_fingerprint(config: Config) -> str:
    """Hash of what decides where the joints go: DH rows and joint limits."""
    return config.fingerprint_of({"dh": [asdict(r) for r in config.robot.dh],
                                  "joint_limits_rad": config.robot.joint_limits_rad})


@dataclass(frozen=True)
class BaselineInfo:
    robot: str
    controller: dict[str, str]  # vendor, model, firmware, serial as the controller reported them
    kinematics_fingerprint: str
    plan_fingerprint: str
    procedure: str
    speed_percent: float
    bidirectional: bool
    recorded_utc: str
    source_run: str
    software_version: str
    joint_temperatures_c: list[float] | None = None
    # the procedure keys the plan was made from (``procedure_keys``), so that ``plan --target-std`` can offer the run
    # that reuses this baseline (``session.stored_candidate``); None in baselines stored before they were recorded
    procedure_keys: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return {"format": BASELINE_FORMAT, **asdict(self)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "BaselineInfo":
        fields = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        return cls(**fields)

    def age_days(self, now: datetime | None = None) -> float:
        now = now or datetime.now(timezone.utc)
        return (now - datetime.fromisoformat(self.recorded_utc)).total_seconds() / 86400.0


def controller_identity(info: ControllerInfo) -> dict[str, str]:
    return {"vendor": info.vendor, "model": info.model, "firmware": info.firmware, "serial": info.serial}


def procedure_keys(config: Config) -> dict[str, Any]:
    """The ``procedure`` keys a plan of ``config`` is made from, as the robot YAML spells them (the config as the
    session used it: a ``calibrate --procedure``/``--speed-percent`` override included, which its YAML lacks)."""
    pc = config.procedure
    return {"name": pc.name, "speed_percent": float(pc.speed_percent),
            "travel_speed_percent": float(pc.travel_speed_percent), "accel_percent": float(pc.accel_percent),
            "base_deg": float(pc.base_deg), "sweep_deg": [float(pc.sweep_from_deg), float(pc.sweep_to_deg)],
            "bidirectional": bool(pc.bidirectional), "inertia": pc.inertia or False}


def describe_for(config: Config, plan: Plan, info: ControllerInfo, source_run: Path,
                 recorded_utc: str | None = None,
                 joint_temperatures_c: list[float] | None = None) -> BaselineInfo:
    return BaselineInfo(
        robot=config.robot.name, controller=controller_identity(info),
        kinematics_fingerprint=kinematics_fingerprint(config), plan_fingerprint=plan.fingerprint(),
        procedure=plan.procedure.name, speed_percent=config.procedure.speed_percent,
        bidirectional=config.procedure.bidirectional,
        recorded_utc=recorded_utc or datetime.now(timezone.utc).isoformat(timespec="seconds"),
        source_run=str(source_run), software_version=__version__,
        joint_temperatures_c=None if joint_temperatures_c is None else [float(t) for t in joint_temperatures_c],
        procedure_keys=procedure_keys(config))


def load_baseline(state: RobotState) -> BaselineInfo | None:
    """The stored baseline's description, or None when none was ever stored."""
    path = state.baseline_info_path
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("format") != BASELINE_FORMAT:
            raise ValueError(f"format {data.get('format')!r}, expected {BASELINE_FORMAT!r}")
        return BaselineInfo.from_json(data)
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise BaselineError(f"the stored baseline description {path} cannot be read ({exc}); "
                            "record a new one with `payload-agent baseline`") from None


def mismatches(stored: BaselineInfo, current: BaselineInfo, max_age_days: float,
               now: datetime | None = None, max_temperature_delta_c: float | None = None) -> list[str]:
    """Every reason the stored baseline does not fit the run about to start (empty: it fits)."""
    reasons = []
    if stored.robot != current.robot:
        reasons.append(f"it was recorded on robot {stored.robot!r}, this is {current.robot!r}")
    for key in ("vendor", "model", "serial"):
        a, b = stored.controller.get(key, ""), current.controller.get(key, "")
        if a != b:
            reasons.append(f"controller {key} changed: {a!r} then, {b!r} now (another robot?)")
    if stored.controller.get("firmware", "") != current.controller.get("firmware", ""):
        reasons.append(f"controller firmware changed: {stored.controller.get('firmware')!r} then, "
                       f"{current.controller.get('firmware')!r} now")
    if stored.kinematics_fingerprint != current.kinematics_fingerprint:
        reasons.append("the kinematics (robot.kinematics / joint limits) changed since it was recorded")
    if stored.plan_fingerprint != current.plan_fingerprint:
        what = []
        if stored.procedure != current.procedure:
            what.append(f"procedure {stored.procedure!r} → {current.procedure!r}")
        if stored.speed_percent != current.speed_percent:
            what.append(f"speed {stored.speed_percent:g} % → {current.speed_percent:g} %")
        if stored.bidirectional != current.bidirectional:
            what.append(f"bidirectional {stored.bidirectional} → {current.bidirectional}")
        detail = ", ".join(what) if what else "poses, sweep range or speeds differ"
        reasons.append(f"the procedure changed since it was recorded ({detail})")
    if (max_temperature_delta_c is not None and stored.joint_temperatures_c is not None
            and current.joint_temperatures_c is not None):
        deltas = [b - a for a, b in zip(stored.joint_temperatures_c, current.joint_temperatures_c)]
        worst = max(range(len(deltas)), key=lambda i: abs(deltas[i]))
        if abs(deltas[worst]) > max_temperature_delta_c:
            reasons.append(f"joint {worst + 1} is {deltas[worst]:+.1f} °C from its temperature when the baseline was "
                           f"recorded (limit ±{max_temperature_delta_c:g} °C, storage.baseline_max_temperature_delta_c): "
                           "friction differs; record the baseline at working temperature")
    age = stored.age_days(now)
    if age > max_age_days:
        reasons.append(f"it is {age:.1f} days old, older than storage.baseline_max_age_days = {max_age_days:g}")
    return reasons


def require_valid(state: RobotState, current: BaselineInfo, max_age_days: float,
                  max_temperature_delta_c: float | None = None) -> BaselineInfo:
    """The stored baseline if it fits the run about to start; BaselineError saying why not otherwise."""
    stored = load_baseline(state)
    if stored is None:
        raise BaselineError(f"no stored empty-flange baseline for robot {current.robot!r} in {state.baseline_dir}; "
                            "record one with `payload-agent baseline --robot ...` (tool removed)")
    reasons = mismatches(stored, current, max_age_days, max_temperature_delta_c=max_temperature_delta_c)
    if reasons:
        raise BaselineError(f"the stored baseline ({state.baseline_dir}, recorded {stored.recorded_utc}) "
                            "no longer matches: " + "; ".join(reasons)
                            + ". Record a new one with `payload-agent baseline --robot ...` (tool removed)")
    return stored


def store_baseline(state: RobotState, run_dir: Path, info: BaselineInfo) -> Path:
    """Copy the run's manifest and empty phase into the state folder, replacing any older baseline whole."""
    run_dir = Path(run_dir)
    manifest = load_manifest(run_dir)
    phase = manifest.get("phases", {}).get("empty", {})
    if phase.get("status") != "complete":
        raise BaselineError(f"{run_dir}: the empty-flange phase is not complete "
                            f"(status {phase.get('status')!r}); nothing stored as baseline")
    state.ensure()
    staging = state.root / "baseline.new"
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir()
    shutil.copy2(run_dir / "manifest.json", staging / "manifest.json")
    shutil.copytree(run_dir / "empty", staging / "empty")
    write_json_atomic(staging / "baseline.json", info.to_json())
    old = state.root / "baseline.old"
    if old.exists():
        shutil.rmtree(old)
    if state.baseline_dir.exists():
        state.baseline_dir.rename(old)
    staging.rename(state.baseline_dir)
    if old.exists():
        shutil.rmtree(old)
    return state.baseline_dir


def status_line(state: RobotState, config: Config, plan: Plan) -> str:
    """One sentence on whether a run would reuse the stored baseline (controller identity not checked)."""
    try:
        stored = load_baseline(state)
    except BaselineError as exc:
        return f"Stored baseline: unusable ({exc})"
    if stored is None:
        return f"Stored baseline: none in {state.baseline_dir}; a run records the empty-flange run first"
    current = BaselineInfo(**{**asdict(stored), "robot": config.robot.name,
                              "kinematics_fingerprint": kinematics_fingerprint(config),
                              "plan_fingerprint": plan.fingerprint(), "procedure": plan.procedure.name,
                              "speed_percent": config.procedure.speed_percent,
                              "bidirectional": config.procedure.bidirectional})
    reasons = mismatches(stored, current, config.storage.baseline_max_age_days)
    if reasons:
        return "Stored baseline: no longer matches (" + "; ".join(reasons) + ")"
    return (f"Stored baseline: recorded {stored.recorded_utc} on {stored.controller.get('model', '?')} "
            f"serial {stored.controller.get('serial') or 'not reported'}; a run records only the loaded run")


def copy_into_run(state: RobotState, info: BaselineInfo, run_dir: Path) -> dict[str, Any]:
    """Copy the stored baseline's empty phase into a run folder, so the run stays self-contained
    (``solve`` and ``report`` work on it later even after the baseline was re-recorded).

    Returns the manifest entry for the run's ``empty`` phase, marked ``from_baseline``.
    """
    manifest = load_manifest(state.baseline_dir)
    phase = dict(manifest.get("phases", {}).get("empty", {}))
    if phase.get("status") != "complete":
        raise BaselineError(f"{state.baseline_dir}: the stored baseline has no complete empty phase; "
                            "record a new one with `payload-agent baseline`")
    shutil.copytree(state.baseline_dir / "empty", Path(run_dir) / "empty")
    phase["from_baseline"] = {"dir": str(state.baseline_dir), "recorded_utc": info.recorded_utc,
                              "source_run": info.source_run}
    return phase
