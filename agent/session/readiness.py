"""The connected readiness checks, written once: `run` stops at the first failure, `doctor` reports them all.

Each check looks at the connected controller (never moving anything) and returns a ``Check``: a line of
the doctor's report and, when it failed, the error `run` raises (``Check.error``, with its exit code).
What a check learns (the controller's identity, where the arm stands) goes into the ``Probe`` the later
checks read. The order is the same for both commands; `run` takes the subset ``RUN_CHECKS``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver
from payload_agent.errors import BaselineError, DataError, PayloadAgentError, RobotNotReadyError, SafetyError
from payload_agent.recording.state import RobotState
from payload_agent.session.connection import SAMPLE_WAIT_S, identify_controller, motion_under_way
from payload_agent.session.stream_density import nominal_period_s
from payload_agent.types import ControllerInfo

OK, FAIL, WARN, INFO = "ok", "FAIL", "warn", "info"
MIN_RATE_SHARE = 0.8  # the measured stream rate must reach this share of the driver's nominal rate


@dataclass
class Check:
    """One line of the readiness report; ``error`` is what `run` raises when it failed."""

    name: str
    status: str  # ok | FAIL | warn | info
    detail: str
    data: dict[str, Any] = field(default_factory=dict)
    error: PayloadAgentError | None = None

    def line(self) -> str:
        return f"  {self.status:<4s}  {self.name:<22s} {self.detail}"


@dataclass
class Probe:
    """The connected robot as the checks see it, filled in as they run."""

    config: Config
    driver: Driver
    plan: Any = None  # the approved plan (None: the configuration could not make one)
    stream_window_s: float = 2.0
    info: ControllerInfo | None = None
    q: np.ndarray | None = None  # joint angles now, rad
    pose: Any = None  # the kinematic cross-check's PoseCheck, when the controller reports a pose
    gains_note: str | None = None  # where the drive gains come from (a stored calibration), None: nominal


def check_identity(p: Probe) -> Check:
    try:
        p.info = info = identify_controller(p.driver)
    except PayloadAgentError as exc:
        return Check("identify", FAIL, f"the controller did not identify itself: {exc}", error=exc)
    return Check("identify", OK, f"{info.vendor} {info.model}, firmware {info.firmware}, serial "
                 f"{info.serial or 'not reported'}", {"vendor": info.vendor, "model": info.model,
                                                      "firmware": info.firmware, "serial": info.serial})


def check_state(p: Probe) -> Check:
    """Motion allowed, and the arm standing still (nobody else moving it): the same rule for run and doctor."""
    try:
        st = p.driver.state()
        busy = motion_under_way(p.driver, st) if st.motion_allowed else None
    except PayloadAgentError as exc:
        return Check("state", FAIL, f"cannot read the controller state: {exc}", error=exc)
    data = {"motion_allowed": st.motion_allowed and not busy, "estop": st.estop,
            "protective_stop": st.protective_stop, "detail": st.detail}
    detail = f" ({st.detail})" if st.detail else ""
    if not st.motion_allowed:
        return Check("state", FAIL, f"motion NOT allowed: {st.reason}{detail}", data,
                     RobotNotReadyError(f"the robot is not ready: {st.reason}"))
    if busy:  # another session or the pendant's program: left alone, nothing is sent
        return Check("state", FAIL, f"motion NOT allowed: {busy}{detail}", data, RobotNotReadyError(
            f"the robot is not ready: {busy}. Wait until it stands still (another session, a cell controller or "
            "the pendant's program may be running); this session sent nothing to the controller"))
    return Check("state", OK, f"motion allowed{detail}", data)


def check_stream(p: Probe) -> Check:
    """The driver's own stream statistics over ``stream_window_s`` of wall time (on a simulated controller,
    rate and gaps on its clock too, which is what a run at its time scale sees)."""
    driver, config, window = p.driver, p.config, p.stream_window_s
    driver.begin_stats()
    time.sleep(window)
    stats = driver.end_stats()
    sample = driver.latest_sample
    p.q = None if sample is None else np.asarray(sample.q, float)
    nominal = 1.0 / driver.nominal_period_s if driver.nominal_period_s > 0 else math.nan
    if stats is None or stats.count < 2:
        n, err = 0 if stats is None else stats.count, driver.stream_error
        return Check("sample stream", FAIL, f"{n} samples in {window:g} s" + (f": {err}" if err else ""),
                     {"samples": n}, err or DataError(f"the sample stream delivered {n} samples in {window:g} s"))
    simulated = config.simulation is not None and stats.controller_rate_hz is not None
    if simulated and driver.sampling_clock == "agent":  # the agent paces the samples in wall time:
        nominal = 1.0 / nominal_period_s(config, driver)  # fewer per simulated second
    nom = f"nominal {nominal:.0f} Hz" if math.isfinite(nominal) else "nominal rate unknown"
    limit, wall_rate = driver.gap_limit_s, stats.achieved_rate_hz
    if simulated:
        rate, gap = stats.controller_rate_hz, stats.largest_gap_s
        text = (f"simulated clock: {rate:.1f} Hz ({nom}), largest gap {1000 * gap:.1f} ms (supervision limit "
                f"{1000 * limit:.0f} ms); wall clock: {stats.count} samples in {window:g} s = {wall_rate:.0f} Hz, "
                f"largest gap {1000 * stats.largest_wall_gap_s:.0f} ms (the simulation runs "
                f"{config.simulation.time_scale:g}× faster than wall time)")
    else:
        rate, gap = wall_rate, stats.largest_wall_gap_s
        text = (f"{stats.count} samples in {window:g} s: {rate:.1f} Hz ({nom}), largest gap {1000 * gap:.1f} ms "
                f"(supervision limit {1000 * limit:.0f} ms)")
    ok = (not math.isfinite(nominal) or rate >= MIN_RATE_SHARE * nominal) and gap <= limit
    data = {"samples": stats.count, "rate_hz": round(rate, 2), "wall_rate_hz": round(wall_rate, 2),
            "nominal_hz": None if not math.isfinite(nominal) else round(nominal, 2),
            "largest_gap_ms": round(1000 * gap, 2), "simulated_time": bool(simulated)}
    return Check("sample stream", OK if ok else FAIL, text, data,
                 None if ok else DataError(f"the sample stream is not good enough for a run: {text}"))


def check_pose(p: Probe) -> Check:
    """The YAML's forward kinematics at the current angles against the flange pose the controller reports."""
    from payload_agent.motion.crosscheck import compare_pose

    config, driver = p.config, p.driver
    if not driver.reports_flange_pose:
        ack = config.safety.unattended_without_pose_check
        return Check("kinematic cross-check", INFO if ack else WARN,
                     "this controller reports no flange pose: the YAML kinematics cannot be checked; an attended run "
                     "shows the planned flange heights and asks"
                     + ("" if ack else "; --unattended needs safety.unattended_without_pose_check"),
                     {"blocks_unattended": not ack})
    try:
        if p.q is None:
            p.q = np.asarray(driver.wait_sample(SAMPLE_WAIT_S).q, float)
        pose = driver.flange_pose()
    except PayloadAgentError as exc:
        return Check("kinematic cross-check", FAIL, f"cannot read the flange pose: {exc}", error=exc)
    if pose is None:
        return Check("kinematic cross-check", WARN, "the controller gave no flange pose")
    p.pose = check = compare_pose(config.robot.kinematics, p.q, pose, config.safety.pose_tolerance_m,
                                  config.safety.pose_tolerance_rad)
    error = None if check.ok else SafetyError(
        "kinematic cross-check failed before any motion: the robot YAML does not describe this robot. "
        f"{check.describe()} Nothing moved after this check.")
    return Check("kinematic cross-check", OK if check.ok else FAIL, check.describe(), check.to_json(), error)


def check_payload(p: Probe) -> Check:
    try:
        s = p.driver.read_payload()
    except PayloadAgentError as exc:
        return Check("payload setting", INFO, f"not readable through this driver ({exc})")
    cog = ", ".join(f"{1000 * c:.1f}" for c in s.cog_m)
    tool = f" (tool {s.tool_num})" if s.tool_num is not None else ""
    return Check("payload setting", INFO, f"the controller has {s.mass_kg:.3f} kg at [{cog}] mm{tool}",
                 {"mass_kg": s.mass_kg, "cog_mm": [1000 * c for c in s.cog_m], "tool_num": s.tool_num})


def check_baseline(p: Probe) -> Check:
    from payload_agent.session import baseline as baselines
    from payload_agent.session.phases import joint_temperatures

    config, state = p.config, RobotState.for_config(p.config)
    if p.plan is None or p.info is None:
        return Check("stored baseline", INFO, "not checked: the plan cannot be made (see configuration)")
    current = baselines.describe_for(config, p.plan, p.info, source_run=Path("."),
                                     joint_temperatures_c=joint_temperatures(p.driver))
    try:
        stored = baselines.require_valid(state, current, config.storage.baseline_max_age_days,
                                         config.storage.baseline_max_temperature_delta_c)
    except BaselineError as exc:
        return Check("stored baseline", WARN, f"{exc}. An attended run records it first; --unattended refuses",
                     {"blocks_unattended": True}, exc)
    return Check("stored baseline", OK, f"recorded {stored.recorded_utc}, fits this robot and procedure "
                 f"({state.baseline_dir})", {"dir": str(state.baseline_dir)})


def check_calibration(p: Probe) -> Check:
    """The stored drive-gain calibration: fits (used), none (nominal gains), or stale (a run refuses it)."""
    from payload_agent.evaluation.calibration import load_calibration

    state = RobotState.for_config(p.config)
    try:
        cal = load_calibration(state, p.config)
    except DataError as exc:
        return Check("drive-gain calibration", FAIL, str(exc), error=exc)
    if cal is None:
        p.gains_note = None
        return Check("drive-gain calibration", INFO, f"none in {state.gains_path}: nominal gains "
                     "(their error is not in the reported uncertainty)")
    joints = ", ".join(str(j + 1) for j in cal.fitted_joints)
    p.gains_note = (f"drive gains from calibration of {cal.created_utc[:10]} ({state.gains_path}, reference "
                    f"{cal.reference_mass_kg:.3f} kg; joints {joints} fitted, others nominal)")
    return Check("drive-gain calibration", OK, f"of {cal.created_utc[:10]}, joints {joints} fitted "
                 f"({state.gains_path})")


CHECKS: dict[str, Callable[[Probe], Check]] = {
    "identify": check_identity, "state": check_state, "stream": check_stream, "pose": check_pose,
    "payload": check_payload, "baseline": check_baseline, "calibration": check_calibration}
DOCTOR_CHECKS = ("identify", "state", "stream", "pose", "payload", "baseline", "calibration")
RUN_CHECKS = ("identify", "state", "calibration", "pose")  # the baseline decides what is recorded, not whether


def first_failure(probe: Probe, names=RUN_CHECKS, seen: Callable[[Check], None] | None = None) -> list[Check]:
    """Run the checks in order and raise the first failure's error (as `run` does); ``seen`` is shown each
    check, the failed one included, first. Returns the checks, all passed."""
    done = []
    for name in names:
        check = CHECKS[name](probe)
        if seen is not None:
            seen(check)
        if check.status == FAIL:
            raise check.error if check.error is not None else RobotNotReadyError(f"{check.name}: {check.detail}")
        done.append(check)
    return done


def every_check(probe: Probe, names=DOCTOR_CHECKS) -> list[Check]:
    """Run every check and report each (as `doctor` does); stops early only when the controller did not
    identify itself."""
    out = []
    for name in names:
        check = CHECKS[name](probe)
        out.append(check)
        if name == "identify" and check.status == FAIL:
            break  # nothing later can be judged without knowing which controller this is
    return out
