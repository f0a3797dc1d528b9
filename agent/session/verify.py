"""`payload-agent verify`: a few seconds of motion that test whether the mounted tool is the expected one.

The expected payload is a tool library entry (``--tool NAME``) or, without one, the controller's
current payload setting. The session is an ordinary one: the robot's session lock, the controller's
identity, readiness and idleness (``motion_under_way``), the kinematic cross-check, a plan the safety
gate approves whole before the first move, every move through the gate, samples recorded into a run
folder (``<stamp>-<robot>-verify``) as they arrive; any exception, Ctrl-C or stalled stream stops the
robot and keeps the data. The statistics are in ``tools.verify_stats``, the motion's choice in
``tools.verify_plan``; the stored empty-flange baseline must fit, as for an unattended run.

Afterwards it reads the controller's payload setting and says whether it matches the expected payload;
with ``apply`` (and a matching tool) it writes the library's payload, reads it back, and fails loudly
(CommunicationError, exit 6) naming the likely cause when the write did not take. A tool that does not
match raises ``ToolMismatchError`` (exit 7) saying what differs and by how much; nothing is written.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any, Callable

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.errors import (CommunicationError, MotionAbortedError, PayloadAgentError, RobotNotReadyError,
                                  ToolMismatchError)
from payload_agent.evaluation.calibration import effective_gains
from payload_agent.motion.planner import make_plan
from payload_agent.motion.safety import SafetyGate
from payload_agent.recording import resting_pose
from payload_agent.recording.recorder import RunRecorder
from payload_agent.recording.rundata import load_phase
from payload_agent.recording.state import RobotState
from payload_agent.session import baseline as baselines
from payload_agent.session.connection import build_driver, identify_controller, motion_under_way, simulated_cell
from payload_agent.session.manifest import RunManifest
from payload_agent.session.phases import PhaseRunner, check_kinematics, joint_temperatures
from payload_agent.session.robot_lock import robot_lock
from payload_agent.tools import library, verify_plan, verify_stats as vs
from payload_agent.tools.library import ToolEntry
from payload_agent.types import PayloadSetting

SAMPLE_WAIT_S = 5.0
SETTING_TOL_KG = 0.005  # a controller setting "matches" the library within these (its own rounding, a typed value)
SETTING_TOL_MM = 1.0


@dataclass(frozen=True)
class VerifyOptions:
    tool: str | None = None  # the library entry to expect; None: the controller's current payload setting
    unattended: bool = False
    assume_yes: bool = False
    apply: bool = False  # write the library's payload when the tool matches (and the setting differs)
    mass_limit_percent: float = 5.0  # the detection targets the motion is chosen for
    cog_limit_mm: float = 10.0
    out: Callable[[str], None] = print
    ask: Callable[[str], str] = input
    detail: Callable[[str], None] | None = None
    cell: Any = None  # an already started SimulatedCell (left running)
    mount: Callable[[Any], None] | None = None  # simulation: mounts the tool on the cell (default: its own truth)


@dataclass
class VerifyOutcome:
    run_dir: Path
    expected: ToolEntry
    result: vs.TestResult
    plan_description: str
    robot_time_s: float
    setting: PayloadSetting | None = None
    setting_matches: bool | None = None
    applied: PayloadSetting | None = None
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"run_dir": str(self.run_dir), "expected": self.expected.to_json(), "test": self.result.to_json(),
                "motion": self.plan_description, "robot_time_s": self.robot_time_s,
                "controller_setting": None if self.setting is None else {
                    "mass_kg": self.setting.mass_kg, "cog_mm": [1000 * c for c in self.setting.cog_m],
                    "tool_num": self.setting.tool_num},
                "setting_matches": self.setting_matches,
                "applied": None if self.applied is None else {"mass_kg": self.applied.mass_kg,
                                                              "cog_mm": [1000 * c for c in self.applied.cog_m]},
                "notes": self.notes}


def setting_matches(setting: PayloadSetting, entry: ToolEntry) -> bool:
    return (abs(setting.mass_kg - entry.mass_kg) <= SETTING_TOL_KG
            and max(abs(1000 * a - b) for a, b in zip(setting.cog_m, entry.cog_mm)) <= SETTING_TOL_MM)


def verify_tool(config: Config, opts: VerifyOptions) -> VerifyOutcome:
    """One verify session (see the module docstring); raises ToolMismatchError when the tool differs."""
    state = RobotState.for_config(config)
    entry = None
    if opts.tool is not None:
        entry = library.require(library.tool_library_path(state.root), config.robot.name, opts.tool)
    build_driver(config)  # a bad driver section is refused before anything starts
    with robot_lock(state, "verify", config.robot.name, opts.out), simulated_cell(config, opts.cell) as cell:
        driver = build_driver(config, cell.options if cell else None)
        if cell is not None:
            (opts.mount or (lambda c: c.mount_tool(True)))(cell)
        outcome = _verify_connected(config, opts, state, driver, entry)
    if not outcome.result.matches:
        err = ToolMismatchError(f"the mounted tool {outcome.result.describe(_expected_name(outcome.expected))}. "
                                f"Nothing was written to the controller; data kept in {outcome.run_dir}")
        err.outcome, err.run_dir = outcome, outcome.run_dir
        raise err
    return outcome


def _expected_name(entry: ToolEntry) -> str:
    return ("the controller's current payload setting" if entry.source == "verified" and entry.name == "controller"
            else f"tool {entry.name!r}") + f" ({entry.mass_kg:.3f} kg, [{', '.join(f'{c:.1f}' for c in entry.cog_mm)}] mm)"


def _verify_connected(config: Config, opts: VerifyOptions, state: RobotState, driver,
                      entry: ToolEntry | None) -> VerifyOutcome:
    out, detail = opts.out, opts.detail or opts.out
    recorder = None
    try:
        driver.connect()
        info = identify_controller(driver)
        ctl = driver.state()
        out(f"Connected: {info.vendor} {info.model}, firmware {info.firmware}")
        if not ctl.motion_allowed:
            raise RobotNotReadyError(f"the robot is not ready: {ctl.reason}")
        busy = motion_under_way(driver, ctl)
        if busy:
            raise RobotNotReadyError(f"the robot is not ready: {busy}. Wait until it stands still; this session sent "
                                     "nothing to the controller")
        full_plan = make_plan(config)
        current = baselines.describe_for(config, full_plan, info, source_run=Path("."),
                                         joint_temperatures_c=joint_temperatures(driver))
        stored = baselines.require_valid(state, current, config.storage.baseline_max_age_days,
                                         config.storage.baseline_max_temperature_delta_c)
        start_q = np.asarray(driver.wait_sample(SAMPLE_WAIT_S).q, float)
        check_kinematics(config, driver, start_q, "before any motion")
        setting = _read_setting(driver, out)
        if entry is None:
            if setting is None:
                raise RobotNotReadyError("verify without --tool compares with the controller's payload setting, "
                                         "which this controller did not report; name a library tool with --tool")
            entry = ToolEntry("controller", setting.mass_kg, tuple(1000 * c for c in setting.cog_m),
                              source="verified")  # type: ignore[arg-type]
        gains = effective_gains(config)[0]
        baseline = load_phase(state.baseline_dir, "empty", np.asarray(gains, float))
        sigma = vs.noise_std(baseline)
        theta0 = vs.theta_of(entry.mass_kg, entry.cog_mm)
        S0 = (np.asarray(entry.covariance_theta_si, float) if entry.covariance_theta_si is not None  # the run's own
              else vs.theta_cov(entry.mass_kg, entry.cog_mm, entry.mass_std_kg, entry.cog_std_mm))  # σ only: diagonal
        resting = resting_pose.standing_at(state.root, start_q)
        from_rest = resting is not None
        cand = verify_plan.choose(config, start_q, baseline, sigma, theta0, S0, opts.mass_limit_percent,
                                  opts.cog_limit_mm, from_rest=from_rest)
        out(f"Expected: {_expected_name(entry)}; baseline of {stored.recorded_utc}, effort noise "
            + sigma.describe())
        out(f"Verify motion: {cand.describe()}")
        if not cand.limits.meets(opts.mass_limit_percent, opts.cog_limit_mm):
            out(f"Note: no verify motion within the baseline's sweeps reaches {opts.mass_limit_percent:g} % / "
                f"{opts.cog_limit_mm:g} mm; this is the most sensitive one")
        if from_rest:
            out(f"The arm rests at {resting.describe()}: the first move runs at travel speed")  # type: ignore[union-attr]
        gate = SafetyGate(config, resting)  # the gate compares it with the angles itself
        verdict = gate.check(cand.plan, start_q)
        out("Safety gate: " + verdict.describe())
        gate.approve(cand.plan, start_q)  # refuses with every problem listed
        if not (opts.unattended or opts.assume_yes):
            if opts.ask("Verify now? The robot will move. [y/N] ").strip().lower() not in ("y", "yes"):
                raise MotionAbortedError("the operator declined; nothing moved")
        recorder = _open_recorder(config, cand, info, driver, entry, stored, state)
        out(f"Run folder: {recorder.run_dir}")
        runner = PhaseRunner(config, driver, gate, recorder, detail)
        t0 = time.monotonic()
        driver.start_stream(runner.sink)
        runner.run_phase("loaded", cand.plan)
        driver.stop_stream()
        if driver.stream_error is not None:
            raise CommunicationError(f"the sample stream failed: {driver.stream_error}")
        loaded = load_phase(recorder.run_dir, "loaded", np.asarray(gains, float))
        windows = {(s.pose, s.joint): s.window for s in cand.segments}
        bins = vs.make_bins(windows, baseline, sigma, cand.segments[0].speed_rad_s, loaded)
        result = vs.glrt(bins, config.robot.kinematics, theta0, S0)
        outcome = VerifyOutcome(recorder.run_dir, entry, result, cand.describe(), cand.robot_time_s, setting)
        out(f"Verify ({cand.robot_time_s:.1f} s robot time, {time.monotonic() - t0:.1f} s wall): "
            + result.describe(_expected_name(entry)))
        if setting is not None:
            outcome.setting_matches = setting_matches(setting, entry)
            out(f"Controller payload setting: {setting.mass_kg:.3f} kg at "
                f"[{', '.join(f'{1000 * c:.1f}' for c in setting.cog_m)}] mm: "
                + ("matches the expected payload" if outcome.setting_matches else "DOES NOT match the expected payload"
                   + ("" if opts.apply else " (verify --apply writes it when the tool matches)")))
        if opts.apply and result.matches and entry.name != "controller" and not outcome.setting_matches:
            outcome.applied = write_and_check(driver, entry, out)
        recorder.update(status="complete", finished_utc=datetime.now().astimezone().isoformat(timespec="seconds"),
                        verify=outcome.to_json())
        (recorder.run_dir / "verify.json").write_text(json.dumps(outcome.to_json(), indent=2) + "\n", "utf-8")
        return outcome
    except BaseException as exc:
        stop_sent = driver.stop()  # only motion this session commanded
        if recorder is not None:
            recorder.update(status="incomplete", stopped_because=str(exc) or type(exc).__name__,
                            session_stop_sent=stop_sent)
            try:
                exc.run_dir = recorder.run_dir  # type: ignore[attr-defined]
            except AttributeError:
                pass
        raise
    finally:
        driver.close()


def _read_setting(driver, out) -> PayloadSetting | None:
    try:
        return driver.read_payload()
    except PayloadAgentError as exc:
        out(f"Controller payload setting: unknown ({exc})")
        return None


def _open_recorder(config: Config, cand, info, driver, entry: ToolEntry, stored, state: RobotState) -> RunRecorder:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}-verify"
    n = 1
    while run_dir.exists():
        n += 1
        run_dir = config.storage.runs_dir / f"{stamp}-{config.robot.name}-verify-{n}"
    manifest = RunManifest(config, cand.plan, "verify", baselines.controller_identity(info), driver.effort_unit,
                           entry.name, {"dir": str(state.baseline_dir), **stored.to_json()}).to_json()
    return RunRecorder(run_dir, {**manifest, "phases_planned": [["loaded", True]], "store_empty": False,
                                 "expected_payload": entry.to_json()})


def write_and_check(driver, entry: ToolEntry, out: Callable[[str], None]) -> PayloadSetting:
    """Write the library's payload to the controller (its inertia too, where the entry has one and the driver
    writes it) and read it back; CommunicationError naming the likely cause when the controller refused it or
    reads back something else."""
    new = PayloadSetting(entry.mass_kg, entry.cog_m)
    tensor = entry.inertia_tensor()
    if tensor is not None:
        why = driver.payload_inertia_support()
        if why:
            out(f"Inertia of tool {entry.name!r} not written: {why}")
        else:
            new = replace(new, inertia_com_kgm2=tuple(tuple(float(v) for v in row) for row in tensor))
    try:
        current = driver.read_payload()
        if current.tool_num is not None:
            new = replace(new, tool_num=current.tool_num)
    except PayloadAgentError:
        pass
    try:
        driver.write_payload(new)
        back = driver.read_payload()
    except PayloadAgentError as exc:
        raise CommunicationError(f"writing the payload of tool {entry.name!r} failed: {exc}. {_likely_cause(driver)}"
                                 ) from None
    if not setting_matches(back, entry):
        raise CommunicationError(
            f"the payload write did NOT take: wrote {entry.mass_kg:.3f} kg at "
            f"[{', '.join(f'{c:.1f}' for c in entry.cog_mm)}] mm, the controller reads back {back.mass_kg:.3f} kg at "
            f"[{', '.join(f'{1000 * c:.1f}' for c in back.cog_m)}] mm. {_likely_cause(driver)}")
    out(f"Applied tool {entry.name!r} and read back: {back.mass_kg:.3f} kg, "
        f"[{', '.join(f'{1000 * c:.1f}' for c in back.cog_m)}] mm")
    return back


def _likely_cause(driver) -> str:
    try:
        st = driver.state()
        mode = f" (controller state: {st.detail or st.reason or 'no detail'})"
    except Exception:
        mode = ""
    return ("Likely cause: the controller does not accept remote writes in its current mode (UR: not in remote "
            "control; Elite: not in remote mode), this user or connection lacks the permission, or the running "
            f"program sets its own payload and overwrote it{mode}. The controller keeps its old payload: set it at "
            "the pendant, then verify again")
