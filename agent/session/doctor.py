"""``payload-agent doctor``: is this robot ready for a run? Connects, looks, never moves anything.

In order, each a line of the report (ok / FAIL / warn / info):

1. the configuration, as ``plan`` checks it (``preflight``: keys, units, driver section, plan,
   safety envelope, stored calibration), and whether another session holds the robot's lock;
2. connect and identify the controller (vendor, model, firmware, serial); an unreachable
   controller names the driver, host and ports;
3. its state: motion allowed or why not (e-stop, protective stop, mode, the arm moving for someone
   else), in the driver's words, by the same rule as ``run``;
4. the sample stream over ``STREAM_WINDOW_S`` of wall time: samples, rate against the driver's
   nominal rate, largest gap against the supervision's limit;
5. the kinematic cross-check: the YAML's forward kinematics at the current angles against
   the flange pose the controller reports (``payload_agent.motion.crosscheck``);
6. the payload the controller has set now (where the driver can read it);
7. whether the stored empty-flange baseline fits (an unattended run needs it) and whether the
   stored drive-gain calibration fits (a run refuses a stale one).

Verdict and exit code: 0 ready (an attended run can start; ``ready_unattended`` says whether an
``--unattended`` one can too), 3 not ready (reachable, but something must be done first), 6
the controller cannot be reached, 2 the configuration is refused. Nothing here can command
motion: the driver's ``move_joints`` is never called.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.errors import (BaselineError, CommunicationError, ConfigError, DataError, PayloadAgentError,
                                  RobotNotReadyError)
from payload_agent.recording.state import RobotState
from payload_agent.session.connection import identify_controller, motion_under_way
from payload_agent.session.robot_lock import current_holder

STREAM_WINDOW_S = 2.0
MIN_RATE_SHARE = 0.8  # the measured rate must reach this share of the driver's nominal rate
OK, FAIL, WARN, INFO = "ok", "FAIL", "warn", "info"


@dataclass
class Check:
    name: str
    status: str  # ok | FAIL | warn | info
    detail: str
    data: dict[str, Any] = field(default_factory=dict)

    def line(self) -> str:
        return f"  {self.status:<4s}  {self.name:<22s} {self.detail}"


@dataclass
class DoctorReport:
    robot: str
    config_source: str
    endpoint: str = ""
    checks: list[Check] = field(default_factory=list)
    reachable: bool = False
    config_ok: bool = True

    @property
    def ready(self) -> bool:
        return self.config_ok and self.reachable and not any(c.status == FAIL for c in self.checks)

    @property
    def ready_unattended(self) -> bool:
        return self.ready and not any(c.status == WARN and c.data.get("blocks_unattended") for c in self.checks)

    @property
    def exit_code(self) -> int:
        if not self.config_ok:
            return ConfigError.exit_code
        if not self.reachable:
            return CommunicationError.exit_code
        return 0 if self.ready else RobotNotReadyError.exit_code

    def verdict(self) -> str:
        if self.ready:
            return "READY" + ("" if self.ready_unattended else " for an attended run (not for --unattended: see warn)")
        why = [c.name for c in self.checks if c.status == FAIL]
        return "NOT READY: " + (", ".join(why) if why else "see above")

    def describe(self) -> str:
        head = f"payload-agent doctor: robot {self.robot!r} ({self.config_source})" + (
            f", controller: {self.endpoint}" if self.endpoint else "")
        return "\n".join([head, *[c.line() for c in self.checks], self.verdict()])

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot, "config": self.config_source, "endpoint": self.endpoint,
                "ready": self.ready, "ready_unattended": self.ready_unattended, "reachable": self.reachable,
                "exit_code": self.exit_code,
                "checks": [{"name": c.name, "status": c.status, "detail": c.detail, **c.data} for c in self.checks]}


def endpoint_text(config: Config, options: Any = None) -> str:
    """Driver, host and every port option, e.g. "elite_ec at 192.168.1.200 (rpc_port 8055, monitor_port 8056)"."""
    opts = options if options is not None else config.driver_options
    host = getattr(opts, "host", None) or (config.driver or {}).get("host")
    ports = [f"{k} {v}" for k, v in (vars(opts).items() if opts is not None and hasattr(opts, "__dict__") else
                                     (config.driver or {}).items()) if k.endswith("port") and v is not None]
    where = f" at {host}" if host else ""
    return f"{config.driver_type}{where}" + (f" ({', '.join(ports)})" if ports else "")


def run_doctor(config: Config, *, cell: Any = None, stream_window_s: float = STREAM_WINDOW_S,
               progress: Callable[[str], None] | None = None) -> DoctorReport:
    """Run every check (see the module docstring); never raises for a robot problem, reports it."""
    from payload_agent.session.connection import build_driver, simulated_cell
    from payload_agent.session.preflight import preflight

    report = DoctorReport(config.robot.name, config.source)
    say = progress or (lambda _text: None)
    pre = preflight(config, calibration=False)
    for p in pre.problems:
        report.config_ok = False
        report.checks.append(Check("configuration", FAIL, str(p), {"key": p.key_path}))
    if pre.ok:
        report.checks.append(Check("configuration", OK, "robot YAML, driver section, plan and safety envelope valid"
                                   + (f"; {'; '.join(pre.notes)}" if pre.notes else "")))
    holder = current_holder(RobotState.for_config(config))
    report.checks.append(Check("session", FAIL if holder else OK,
                               f"another payload-agent session holds this robot: {holder.describe()}" if holder
                               else "no other payload-agent session holds this robot",
                               {"holder": holder.to_json() if holder else None}))
    if any(p.key_path.startswith(("driver", "effort", "simulation")) for p in pre.problems):
        return report  # no driver to connect with
    # with other configuration problems, still connect: the cross-check may name the cause (a DH sign...)
    try:
        with simulated_cell(config, cell) as live_cell:
            driver = build_driver(config, live_cell.options if live_cell is not None else None)
            report.endpoint = endpoint_text(config, driver.options)
            say(f"Connecting to {report.endpoint} ...")
            try:
                driver.connect()
            except PayloadAgentError as exc:
                report.checks.append(Check("connect", FAIL, f"cannot reach {report.endpoint}: {exc}"))
                return report
            try:
                report.reachable = True
                _connected_checks(config, driver, report, stream_window_s, pre.plan, live_cell)
            finally:
                driver.close()
    except CommunicationError as exc:  # e.g. the simulated controller could not listen
        report.checks.append(Check("connect", FAIL, str(exc)))
    return report


def _connected_checks(config: Config, driver, report: DoctorReport, window_s: float, plan, cell) -> None:
    try:
        info = identify_controller(driver)
    except PayloadAgentError as exc:
        report.checks.append(Check("identify", FAIL, f"the controller did not identify itself: {exc}"))
        if isinstance(exc, CommunicationError):  # it accepts but does not speak the protocol: as `run`, exit 6
            report.reachable = False
        return
    report.checks.append(Check("identify", OK, f"{info.vendor} {info.model}, firmware {info.firmware}, "
                               f"serial {info.serial or 'not reported'}", {"vendor": info.vendor, "model": info.model,
                                                               "firmware": info.firmware, "serial": info.serial}))
    try:
        st = driver.state()
        busy = motion_under_way(driver, st) if st.motion_allowed else None  # the same rule as `run`
        if busy:
            st = dataclasses.replace(st, motion_allowed=False, reason=busy)
        status = OK if st.motion_allowed else FAIL
        text = ("motion allowed" if st.motion_allowed else f"motion NOT allowed: {st.reason}") + (
            f" ({st.detail})" if st.detail else "")
        report.checks.append(Check("state", status, text, {"motion_allowed": st.motion_allowed, "estop": st.estop,
                                                            "protective_stop": st.protective_stop,
                                                            "detail": st.detail}))
    except PayloadAgentError as exc:
        report.checks.append(Check("state", FAIL, f"cannot read the controller state: {exc}"))
        if isinstance(exc, CommunicationError):
            report.reachable = False
    q = _stream_check(driver, report, window_s, config)
    if q is not None:
        _pose_check(config, driver, q, report)
    _payload_check(driver, report)
    _stored_state_checks(config, driver, report, plan, info)


def _stream_check(driver, report: DoctorReport, window_s: float, config: Config) -> np.ndarray | None:
    times: list[tuple[float, float | None]] = []
    last: list = []
    lock = threading.Lock()

    def sink(sample) -> None:
        with lock:
            times.append((sample.t_recv, sample.t_ctrl))
            last[:] = [sample]

    try:
        driver.start_stream(sink)
        time.sleep(window_s)
        driver.stop_stream()
    except PayloadAgentError as exc:
        report.checks.append(Check("sample stream", FAIL, f"no stream: {exc}"))
        return None
    with lock:
        t_wall = np.asarray([a for a, _ in times], float)
        t_ctrl = np.asarray([np.nan if b is None else b for _, b in times], float)
        sample = last[0] if last else None
    nominal = 1.0 / driver.nominal_period_s if driver.nominal_period_s > 0 else math.nan
    if len(t_wall) < 2:
        err = driver.stream_error
        report.checks.append(Check("sample stream", FAIL, f"{len(t_wall)} samples in {window_s:g} s"
                                   + (f": {err}" if err else ""), {"samples": int(len(t_wall))}))
        return None if sample is None else np.asarray(sample.q, float)
    wall_rate = (len(t_wall) - 1) / (t_wall[-1] - t_wall[0])
    wall_gap = float(np.max(np.diff(t_wall)))
    simulated = config.simulation is not None and np.all(np.isfinite(t_ctrl))
    if simulated and driver.sampling_clock == "agent":  # the agent paces the samples in wall time:
        nominal /= config.simulation.time_scale  # fewer per simulated second
    nom = f"nominal {nominal:.0f} Hz" if math.isfinite(nominal) else "nominal rate unknown"
    if simulated:  # the simulated controller's own clock: what a run at its time scale sees
        rate = (len(t_ctrl) - 1) / max(t_ctrl[-1] - t_ctrl[0], 1e-9)
        gap = float(np.max(np.diff(t_ctrl)))
        limit = driver.gap_limit_s  # the supervision's limit (sims set their own: they share a loaded CPU)
        ts = config.simulation.time_scale
        text = (f"simulated clock: {rate:.1f} Hz ({nom}), largest gap {1000 * gap:.1f} ms "
                f"(supervision limit {1000 * limit:.0f} ms); wall clock: {len(t_wall)} samples in {window_s:g} s = "
                f"{wall_rate:.0f} Hz, largest gap {1000 * wall_gap:.0f} ms (the simulation runs {ts:g}× faster "
                "than wall time)")
    else:
        rate, gap, limit = wall_rate, wall_gap, driver.gap_limit_s
        text = (f"{len(t_wall)} samples in {window_s:g} s: {rate:.1f} Hz ({nom}), largest gap "
                f"{1000 * gap:.1f} ms (supervision limit {1000 * limit:.0f} ms)")
    ok = (not math.isfinite(nominal) or rate >= MIN_RATE_SHARE * nominal) and gap <= limit
    report.checks.append(Check(
        "sample stream", OK if ok else FAIL, text,
        {"samples": int(len(t_wall)), "rate_hz": round(rate, 2), "wall_rate_hz": round(wall_rate, 2),
         "nominal_hz": None if not math.isfinite(nominal) else round(nominal, 2),
         "largest_gap_ms": round(1000 * gap, 2), "simulated_time": bool(simulated)}))
    return np.asarray(sample.q, float)


def _pose_check(config: Config, driver, q: np.ndarray, report: DoctorReport) -> None:
    from payload_agent.motion.crosscheck import compare_pose

    if not driver.reports_flange_pose:
        ack = config.safety.unattended_without_pose_check
        report.checks.append(Check("kinematic cross-check", WARN if not ack else INFO,
                                   "this controller reports no flange pose: the YAML kinematics cannot be checked; "
                                   "an attended run shows the planned flange heights and asks"
                                   + ("" if ack else "; --unattended needs safety.unattended_without_pose_check"),
                                   {"blocks_unattended": not ack}))
        return
    try:
        pose = driver.flange_pose()
    except PayloadAgentError as exc:
        report.checks.append(Check("kinematic cross-check", FAIL, f"cannot read the flange pose: {exc}"))
        return
    if pose is None:
        report.checks.append(Check("kinematic cross-check", FAIL, "the controller gave no flange pose"))
        return
    check = compare_pose(config.robot.kinematics, q, pose, config.safety.pose_tolerance_m,
                         config.safety.pose_tolerance_rad)
    report.checks.append(Check("kinematic cross-check", OK if check.ok else FAIL, check.describe(), check.to_json()))


def _payload_check(driver, report: DoctorReport) -> None:
    try:
        p = driver.read_payload()
    except PayloadAgentError as exc:
        report.checks.append(Check("payload setting", INFO, f"not readable through this driver ({exc})"))
        return
    cog = ", ".join(f"{1000 * c:.1f}" for c in p.cog_m)
    tool = f" (tool {p.tool_num})" if p.tool_num is not None else ""
    report.checks.append(Check("payload setting", INFO, f"the controller has {p.mass_kg:.3f} kg at [{cog}] mm{tool}",
                               {"mass_kg": p.mass_kg, "cog_mm": [1000 * c for c in p.cog_m], "tool_num": p.tool_num}))


def _stored_state_checks(config: Config, driver, report: DoctorReport, plan, info) -> None:
    from payload_agent.evaluation.calibration import load_calibration

    state = RobotState.for_config(config)
    report.checks.append(_baseline_check(config, driver, state, plan, info))
    try:
        cal = load_calibration(state, config)
    except DataError as exc:
        report.checks.append(Check("drive-gain calibration", FAIL, str(exc)))
        return
    if cal is None:
        report.checks.append(Check("drive-gain calibration", INFO, f"none in {state.gains_path}: nominal gains "
                                   "(their error is not in the reported uncertainty)"))
    else:
        report.checks.append(Check("drive-gain calibration", OK, f"of {cal.created_utc[:10]}, joints "
                                   f"{', '.join(str(j + 1) for j in cal.fitted_joints)} fitted ({state.gains_path})"))


def _baseline_check(config: Config, driver, state: RobotState, plan, info) -> Check:
    from payload_agent.session import baseline as baselines
    from payload_agent.session.phases import joint_temperatures

    if plan is None:
        return Check("stored baseline", INFO, "not checked: the plan cannot be made (see configuration)")
    current = baselines.describe_for(config, plan, info, source_run=Path("."),
                                     joint_temperatures_c=joint_temperatures(driver))
    try:
        stored = baselines.require_valid(state, current, config.storage.baseline_max_age_days,
                                         config.storage.baseline_max_temperature_delta_c)
    except BaselineError as exc:
        return Check("stored baseline", WARN, f"{exc}. An attended run records it first; --unattended refuses",
                     {"blocks_unattended": True})
    return Check("stored baseline", OK, f"recorded {stored.recorded_utc}, fits this robot and procedure "
                 f"({state.baseline_dir})", {"dir": str(state.baseline_dir)})
