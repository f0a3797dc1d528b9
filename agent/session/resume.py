"""Resuming an incomplete run (`payload-agent run --resume RUN_DIR`): what is left, and whether it still fits.

A run folder may be resumed only by the same robot (controller identity), with the same robot
YAML (every section that decides motion or analysis) and the same plan; then only the sweeps
that did not finish are recorded again, into the same folder.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path

from payload_agent.configuration.config import Config
from payload_agent.errors import ConfigError, PayloadAgentError, RobotNotReadyError
from payload_agent.motion.planner import Plan
from payload_agent.recording.rundata import load_manifest
from payload_agent.session.baseline import BaselineInfo, controller_identity
from payload_agent.types import ControllerInfo

FINGERPRINT_SECTIONS = ("robot", "effort", "driver", "procedure", "safety")


def config_fingerprint(config: Config) -> str:
    return config.fingerprint(*FINGERPRINT_SECTIONS)


@dataclass
class ResumeState:
    run_dir: Path
    manifest: dict
    mode: str
    phases: list[tuple[str, bool, set[str]]]  # phase, tool mounted, names of its sweeps already complete
    store_empty: bool
    stored_info: BaselineInfo | None

    def check_controller(self, info: ControllerInfo) -> None:
        then, now = self.manifest.get("controller") or {}, controller_identity(info)
        if then != now:
            raise RobotNotReadyError(f"{self.run_dir} was recorded on {then}, this controller is {now}: "
                                     "a run can only be resumed on the robot that started it")


def load_resume(config: Config, plan: Plan, run_dir: Path) -> ResumeState:
    """What is left of an incomplete run; ConfigError when the YAML or the plan changed since."""
    run_dir = Path(run_dir)
    manifest = load_manifest(run_dir)
    if manifest.get("status") == "complete":
        raise ConfigError("--resume", f"{run_dir} is complete; nothing to resume")
    recorded = manifest.get("robot")
    if recorded and recorded != config.robot.name:
        raise ConfigError("--resume", f"this run belongs to {recorded} (recorded with "
                                      f"{manifest.get('config_source', 'its own YAML')}), not to {config.robot.name}: "
                                      f"resume it with --robot {recorded}")
    if manifest.get("config_fingerprint") != config_fingerprint(config):
        raise ConfigError("--resume", f"the robot YAML changed since {run_dir} was recorded: "
                                      f"{changed_keys(manifest.get('config') or {}, config.raw)}; "
                                      "undo that change, or start a new run")
    if manifest.get("plan_fingerprint") != plan.fingerprint():
        raise ConfigError("--resume", f"the plan changed since {run_dir} was recorded although the YAML did not "
                                      f"(the procedure file {plan.procedure.name!r} changed?); start a new run instead")
    all_sweeps = {m.recorded_name for m in plan.moves if m.recorded_name}  # sweeps and wrist moves
    phases = []
    for phase, mounted in manifest.get("phases_planned") or []:
        entry = manifest.get("phases", {}).get(phase, {})
        done = {s["name"] for s in entry.get("sweeps", []) + entry.get("wrist_moves", []) if s.get("status") == "complete"}
        if done != all_sweeps:
            phases.append((phase, bool(mounted), done))
    if not phases:
        raise ConfigError("--resume", f"{run_dir} has every sweep recorded; analyse it with "
                                      f"`payload-agent solve {run_dir}`")
    base = manifest.get("baseline")
    stored = BaselineInfo.from_json(base) if base else None
    return ResumeState(run_dir, manifest, manifest.get("mode", "identify"), phases,
                       bool(manifest.get("store_empty")), stored)


def changed_keys(then: dict, now: dict) -> str:
    """Which keys of the compared sections differ between the recorded YAML and this one, e.g.
    "procedure.speed_percent: 10 then, 20 now" (a whole section when it appeared or went)."""
    out = []
    for section in FINGERPRINT_SECTIONS:
        a, b = then.get(section), now.get(section)
        if Config.fingerprint_of(a) == Config.fingerprint_of(b):
            continue
        if not (isinstance(a, dict) and isinstance(b, dict)):
            out.append(f"section {section}")
            continue
        for key in sorted(set(a) | set(b), key=str):
            if Config.fingerprint_of(a.get(key)) != Config.fingerprint_of(b.get(key)):
                short = lambda v: "absent" if v is None else (repr(v) if len(repr(v)) <= 40 else "(changed)")
                out.append(f"{section}.{key}: {short(a.get(key))} then, {short(b.get(key))} now")
    return "; ".join(out) or "sections " + ", ".join(FINGERPRINT_SECTIONS)


def continue_command(run_dir: Path, robot: str | None) -> str | None:
    """The command that continues a run folder a session left behind: `run --resume` while sweeps are
    missing, `solve` when everything was recorded and only the analysis failed; None if nothing is left."""
    try:
        manifest = load_manifest(Path(run_dir))
    except PayloadAgentError:
        return None
    robot_arg = f" --robot {shlex.quote(robot)}" if robot else ""
    if manifest.get("status") == "incomplete":
        return f"payload-agent run{robot_arg} --resume {shlex.quote(str(run_dir))}"
    if manifest.get("status") == "complete" and manifest.get("mode") != "baseline":
        return f"payload-agent solve {shlex.quote(str(run_dir))}"
    return None
