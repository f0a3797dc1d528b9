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

from dataclasses import dataclass, field
from typing import Any, Callable

from payload_agent.configuration.config import Config
from payload_agent.errors import CommunicationError, ConfigError, PayloadAgentError, RobotNotReadyError
from payload_agent.recording.state import RobotState
from payload_agent.session.readiness import FAIL, OK, WARN, Check
from payload_agent.session.robot_lock import current_holder

STREAM_WINDOW_S = 2.0


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
    """Every readiness check (``readiness.py``, the same checks `run` stops at), each reported."""
    from payload_agent.session.readiness import Probe, every_check

    for check in every_check(Probe(config, driver, plan, window_s)):
        report.checks.append(check)
        if check.name in ("identify", "state") and isinstance(check.error, CommunicationError):
            report.reachable = False  # it accepts but does not speak the protocol: as `run`, exit 6
