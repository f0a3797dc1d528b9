"""Robot YAML -> typed, validated configuration.

Units in YAML are the ones integrators read on teach pendants (mm, deg, percent);
everything inside the dataclasses is SI (m, rad, rad/s) unless a name says otherwise.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from payload_agent.errors import ConfigError
from payload_agent.model.kinematics import DHRow, Kinematics
from payload_agent.configuration import units
from payload_agent.configuration.paths import resolve_against, state_home
from payload_agent.configuration.procedure import load_procedure
from payload_agent.configuration.wrist_procedure import inertia_procedure_key
from payload_agent.configuration.joint_systematics import JointSystematicsConfig, joint_systematics
from payload_agent.configuration.simulation import SimulationConfig, parse_simulation
from payload_agent.configuration.watch import WatchConfig, parse_watch
from payload_agent.configuration.yamlcheck import Node, check_numbers, load_yaml
from payload_agent.drivers.base import DriverOptions
from payload_agent.drivers.registry import parse_driver_options

N_JOINTS = 6
EFFORT_UNITS = ("percent_rated", "permille_rated", "A", "Nm")
DEFAULT_BASELINE_MAX_AGE_DAYS = 7.0  # friction changes with temperature and wear; re-record weekly
# DH lengths of a production arm are known to a fraction of a mm (machining and assembly
# tolerances); an arm with a measured (calibrated) kinematic model can declare less
DEFAULT_LENGTH_UNCERTAINTY_MM = 0.5
# Gearbox friction falls markedly as the joints warm up from cold; a baseline recorded on a cold
# robot does not describe a warm one. 10 °C is roughly cold start vs. after an hour of work.
DEFAULT_BASELINE_MAX_TEMPERATURE_DELTA_C = 10.0
@dataclass(frozen=True)
class RobotConfig:
    name: str
    model: str
    dh: tuple[DHRow, ...]
    joint_limits_rad: tuple[tuple[float, float], ...]
    max_joint_speed_rad_s: float
    max_joint_accel_rad_s2: float
    # standard uncertainty of every non-zero DH length (a_i, d_i), independent per length; the
    # general solver propagates it into the reported covariance (robot.kinematics.length_uncertainty_mm)
    length_uncertainty_m: float = DEFAULT_LENGTH_UNCERTAINTY_MM / 1000.0
    # joint stiffness, zero and friction-asymmetry uncertainties (robot.kinematics.*, robot.friction_asymmetry_percent)
    joints: JointSystematicsConfig = JointSystematicsConfig()

    @property
    def kinematics(self) -> Kinematics:
        return Kinematics(self.dh)


@dataclass(frozen=True)
class EffortConfig:
    unit: str
    gains_nm_per_unit: tuple[float, ...]  # multiply the controller's effort by this to get N·m


@dataclass(frozen=True)
class ProcedureConfig:
    name: str
    speed_percent: float  # sweep speed, percent of max joint speed
    travel_speed_percent: float  # moves between sweeps
    accel_percent: float  # percent of max joint acceleration
    base_deg: float  # joint-1 angle the whole procedure runs at
    sweep_from_deg: float
    sweep_to_deg: float
    bidirectional: bool
    solver: str
    inertia: str | None = None  # wrist procedure for the inertia tensor (procedures/wrist_*.yaml), None: off


@dataclass(frozen=True)
class SafetyConfig:
    joint_limit_margin_rad: float
    max_speed_percent: float
    approach_speed_percent: float
    floor_z_m: float
    reach_box_m: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    motion_timeout_factor: float
    # supervision: stream gap that stops the arm (None: max(5 sample periods, 50 ms)), stop acknowledgement wait
    max_stream_gap_s: float | None = None
    stop_ack_timeout_s: float = 2.0
    # kinematic cross-check: YAML forward kinematics vs the pose the controller reports
    pose_tolerance_m: float = 0.005
    pose_tolerance_rad: float = math.radians(1.0)
    # a driver without a reported pose: an unattended run needs this explicit acknowledgement
    unattended_without_pose_check: bool = False
    max_wrist_speed_percent: float | None = None  # wrist moves of the inertia part (None: max_speed_percent)
    # the inertia part's wrist moves accelerate at most this (their 100 %; None: robot.max_joint_accel_deg_s2)
    max_wrist_accel_rad_s2: float | None = None
    # the tool's farthest point from the flange centre: that sphere kept above the floor, in the box (None: flange)
    tool_radius_m: float | None = None


@dataclass(frozen=True)
class StorageConfig:
    runs_dir: Path
    state_dir: Path  # per-robot state lives in state_dir/<robot.name>/ (see payload_agent.recording.state)
    baseline_max_age_days: float  # a stored empty-flange baseline older than this is refused
    baseline_max_temperature_delta_c: float  # ... and one recorded this much colder/warmer (any joint)


@dataclass(frozen=True)
class Config:
    source: str
    robot: RobotConfig
    effort: EffortConfig
    driver: Mapping[str, Any]  # the raw YAML section (snapshot); driver_options is the typed, checked form
    procedure: ProcedureConfig
    safety: SafetyConfig
    storage: StorageConfig
    simulation: SimulationConfig | None
    watch: WatchConfig | None = None
    driver_options: DriverOptions | None = None
    raw: Mapping[str, Any] = field(repr=False, compare=False, default_factory=dict)

    @property
    def driver_type(self) -> str:
        return str(self.driver["type"])

    @property
    def wrist_accel_rad_s2(self) -> float:
        """The inertia part's wrist moves' 100 % acceleration and cap: ``safety.max_wrist_accel_deg_s2``, else the
        robot's ``max_joint_accel_deg_s2`` (a robot that takes more on its wrist than the planning value for the
        whole arm, with a source: the inertia fit's information grows with the acceleration squared)."""
        cap = self.safety.max_wrist_accel_rad_s2
        return self.robot.max_joint_accel_rad_s2 if cap is None else cap

    def fingerprint(self, *sections: str) -> str:
        """Stable hash of the named raw sections (what a stored baseline depends on)."""
        return self.fingerprint_of({s: self.raw.get(s) for s in sections})

    @staticmethod
    def fingerprint_of(data: Any) -> str:
        """Stable short hash of JSON-able data."""
        return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:16]


SECTIONS = ("robot", "effort", "driver", "procedure", "safety", "storage", "simulation", "watch")
ROBOT_KEYS = ("name", "model", "kinematics", "joint_limits_deg", "max_joint_speed_deg_s", "max_joint_accel_deg_s2",
              "friction_asymmetry_percent", "friction_change_percent", "tool_cable_fitted")
KINEMATICS_KEYS = ("convention", "dh", "length_uncertainty_mm", "stiffness_nm_per_rad", "stiffness_uncertainty_percent",
                   "zero_offset_uncertainty_deg")
DH_KEYS = ("a_mm", "d_mm", "alpha_deg", "offset_deg")
EFFORT_KEYS = ("unit", "gains_nm_per_unit")
PROCEDURE_KEYS = ("name", "speed_percent", "travel_speed_percent", "accel_percent", "base_deg", "sweep_deg",
                  "bidirectional", "solver", "inertia")
SAFETY_KEYS = ("joint_limit_margin_deg", "max_speed_percent", "approach_speed_percent", "floor_z_mm", "reach_box_mm",
               "motion_timeout_factor", "max_stream_gap_ms", "stop_ack_timeout_s", "pose_tolerance_mm",
               "max_wrist_speed_percent", "max_wrist_accel_deg_s2", "tool_radius_mm",
               "pose_tolerance_deg", "unattended_without_pose_check")
STORAGE_KEYS = ("runs_dir", "state_dir", "baseline_max_age_days", "baseline_max_temperature_delta_c")
# driver keys that were removed, and what replaces them (a stale YAML gets told, not ignored)
REMOVED_DRIVER_KEYS = {
    "max_joint_accel_rad_s2": "there is one acceleration setting, robot.max_joint_accel_deg_s2 (deg/s²); the "
                              "driver derives its controller's acceleration scale from it. Delete this key",
}


def read_config_file(path: str | Path) -> Any:
    """The parsed YAML of a robot file (strict: duplicate keys are errors naming the key)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError("<file>", f"cannot read {path}: {exc.strerror or exc}", str(path)) from None
    return load_yaml(text, str(path))


def load_config(path: str | Path) -> Config:
    path = Path(path)
    try:
        return parse_config(read_config_file(path), source=str(path), base_dir=path.resolve().parent)
    except ConfigError as exc:  # raised by a plugin (driver registry, procedure file) without the file name
        if exc.source is None:
            raise ConfigError(exc.key_path, exc.problem, str(path)) from None
        raise


def parse_config(data: Any, source: str = "<config>", base_dir: Path | None = None) -> Config:
    """Validate a robot YAML (already parsed); relative paths in it are resolved against ``base_dir``."""
    top = Node(data, "", source).allow(SECTIONS)
    robot = _robot(top.child("robot", keys=ROBOT_KEYS))
    effort = _effort(top.child("effort", keys=EFFORT_KEYS))
    driver_node = top.child("driver")
    for key, why in REMOVED_DRIVER_KEYS.items():
        if driver_node.has(key):
            raise driver_node.error(key, f"no longer exists: {why}")
    driver, driver_options = _driver(driver_node)
    procedure = _procedure(top.child("procedure", keys=PROCEDURE_KEYS))
    safety = _safety(top.child("safety", keys=SAFETY_KEYS), robot)
    storage = _storage(top.child("storage", required=False, keys=STORAGE_KEYS), base_dir, robot.name)
    sim_node = top.child("simulation", required=False)
    simulation = parse_simulation(sim_node) if sim_node is not None else None
    watch_node = top.child("watch", required=False)
    watch = parse_watch(watch_node, base_dir) if watch_node is not None else None
    top.reject_unknown(SECTIONS)
    if procedure.speed_percent > safety.max_speed_percent:
        raise ConfigError("procedure.speed_percent",
                          f"{procedure.speed_percent:g} % exceeds safety.max_speed_percent "
                          f"({safety.max_speed_percent:g} %)", source)
    if procedure.travel_speed_percent > safety.max_speed_percent:
        raise ConfigError("procedure.travel_speed_percent",
                          f"{procedure.travel_speed_percent:g} % exceeds safety.max_speed_percent "
                          f"({safety.max_speed_percent:g} %)", source)
    return Config(source, robot, effort, driver, procedure, safety, storage, simulation, watch, driver_options,
                  raw=data)


def parse_kinematics(kin: Node, robot: Node | None = None) -> tuple[tuple[DHRow, ...], float, JointSystematicsConfig]:
    """``robot.kinematics``: the DH rows (offset_deg required, units checked), the length uncertainty (mm)
    and the joints' declared systematics (with ``robot.friction_asymmetry_percent`` when ``robot`` is given)."""
    kin.string("convention", choices=["standard_dh"])
    rows_raw = kin.raw("dh")
    if not isinstance(rows_raw, list) or len(rows_raw) != N_JOINTS:
        raise kin.error("dh", f"expected a list of {N_JOINTS} rows (one per joint), got {rows_raw!r:.60}")
    rows, raw_rows = [], []
    for i, row in enumerate(rows_raw):
        r = Node(row, kin.key(f"dh[{i}]"), kin.source).allow(DH_KEYS)
        a_mm = r.number("a_mm", min=-5000, max=5000)
        d_mm = r.number("d_mm", min=-5000, max=5000)
        alpha = r.number("alpha_deg", min=-360, max=360)
        if not r.has("offset_deg") or r.data["offset_deg"] is None:  # it changes where the robot goes: no default
            r.raw("offset_deg", None)  # a misspelt key is named first
            raise r.error("offset_deg", "is required: the joint's zero offset in degrees (DH θ = controller angle "
                                        "+ offset_deg). Write 0 explicitly if the controller's zero is the DH zero; "
                                        "a wrong value moves the robot somewhere else")
        offset = r.number("offset_deg", min=-360, max=360)
        r.reject_unknown()
        raw_rows.append((a_mm, d_mm, alpha, offset))
        rows.append(DHRow(a_m=a_mm / 1000.0, d_m=d_mm / 1000.0, alpha_rad=math.radians(alpha),
                          offset_rad=math.radians(offset)))
    units.check_dh(raw_rows, kin.key("dh"), kin.source)
    length_std_mm = kin.number("length_uncertainty_mm", DEFAULT_LENGTH_UNCERTAINTY_MM, min=0, max=50)
    joints = joint_systematics(kin, robot)
    kin.reject_unknown()
    return tuple(rows), length_std_mm, joints


def _robot(node: Node) -> RobotConfig:
    name = node.string("name")
    model = node.string("model")
    rows, length_std_mm, joints = parse_kinematics(node.child("kinematics", keys=KINEMATICS_KEYS), node)
    limits_raw = node.raw("joint_limits_deg")
    if not isinstance(limits_raw, list) or len(limits_raw) != N_JOINTS:
        raise node.error("joint_limits_deg", f"expected {N_JOINTS} [min, max] pairs, got {limits_raw!r:.60}")
    limits = []
    for i, pair in enumerate(limits_raw):
        lo, hi = check_numbers(pair, node.key(f"joint_limits_deg[{i}]"), 2, source=node.source)
        units.check_joint_limit(lo, hi, node.key(f"joint_limits_deg[{i}]"), node.source)
        if lo >= hi:
            raise node.error(f"joint_limits_deg[{i}]", f"min ({lo:g}) must be below max ({hi:g})")
        limits.append((lo, hi))
    units.check_joint_limits_unit(limits, node.key("joint_limits_deg"), node.source)
    limits = [(math.radians(lo), math.radians(hi)) for lo, hi in limits]
    speed = node.number("max_joint_speed_deg_s", gt=0, max=1000)
    accel = node.number("max_joint_accel_deg_s2", gt=0, max=10000)
    node.reject_unknown()
    return RobotConfig(name, model, rows, tuple(limits), math.radians(speed), math.radians(accel),
                       length_std_mm / 1000.0, joints)


def _effort(node: Node) -> EffortConfig:
    unit = node.string("unit", choices=EFFORT_UNITS)
    gains = node.per_joint("gains_nm_per_unit", N_JOINTS, gt=0)
    node.reject_unknown()
    return EffortConfig(unit, gains)


def _driver(node: Node) -> tuple[Mapping[str, Any], DriverOptions]:
    node.string("type")
    return dict(node.data), parse_driver_options(node.data, node.path, node.source)


def _procedure(node: Node) -> ProcedureConfig:
    name = node.string("name")
    try:
        load_procedure(name)  # `plan` refuses an unknown procedure as `run` would
    except ConfigError as exc:
        raise node.error("name", exc.problem) from None
    speed = node.number("speed_percent", gt=0, max=100)
    travel = node.number("travel_speed_percent", gt=0, max=100)
    accel = node.number("accel_percent", gt=0, max=100)
    base = node.number("base_deg", min=-360, max=360)
    sweep = node.numbers("sweep_deg", 2, min=-90, max=90)
    if sweep[1] - sweep[0] < 10:
        raise node.error("sweep_deg", f"needs at least 10 degrees of travel from first to second value, got {sweep}")
    bidirectional = node.boolean("bidirectional")
    solver = node.string("solver", choices=["three-step", "general"])
    inertia = inertia_procedure_key(node)
    node.reject_unknown()
    return ProcedureConfig(name, speed, travel, accel, base, sweep[0], sweep[1], bidirectional, solver, inertia)


def _safety(node: Node, robot: RobotConfig) -> SafetyConfig:
    margin = node.number("joint_limit_margin_deg", min=0, max=45)
    max_speed = node.number("max_speed_percent", gt=0, max=100)
    approach = node.number("approach_speed_percent", gt=0, max=100)
    floor = node.number("floor_z_mm", min=-5000, max=5000)
    box = node.child("reach_box_mm", keys=("x", "y", "z"))
    axes = []
    for axis in ("x", "y", "z"):
        lo, hi = box.numbers(axis, 2, min=-5000, max=5000)
        if lo >= hi:
            raise box.error(axis, f"min ({lo:g}) must be below max ({hi:g})")
        axes.append((lo / 1000.0, hi / 1000.0))
    box.reject_unknown(["x", "y", "z"])
    timeout = node.number("motion_timeout_factor", 2.0, min=1.2, max=20)
    gap_ms = node.number("max_stream_gap_ms", None, min=5, max=1000) if node.has("max_stream_gap_ms") else None
    ack_s = node.number("stop_ack_timeout_s", 2.0, min=0.1, max=10)
    pose_mm = node.number("pose_tolerance_mm", 5.0, gt=0, max=50)
    pose_deg = node.number("pose_tolerance_deg", 1.0, gt=0, max=10)
    no_pose_ok = node.boolean("unattended_without_pose_check", False)
    wrist = node.number("max_wrist_speed_percent", max_speed, gt=0, max=100)  # the inertia part's fast wrist moves
    wrist_accel = (math.radians(node.number("max_wrist_accel_deg_s2", gt=0, max=10000))
                   if node.has("max_wrist_accel_deg_s2") else None)
    tool_r = node.number("tool_radius_mm", min=0, max=2000) / 1000.0 if node.has("tool_radius_mm") else None
    node.reject_unknown()
    if approach > max_speed:
        raise node.error("approach_speed_percent", f"{approach:g} % exceeds max_speed_percent ({max_speed:g} %)")
    return SafetyConfig(math.radians(margin), max_speed, approach, floor / 1000.0, tuple(axes), timeout,
                        None if gap_ms is None else gap_ms / 1000.0, ack_s, pose_mm / 1000.0, math.radians(pose_deg),
                        no_pose_ok, wrist, wrist_accel, tool_r)


def _storage(node: Node | None, base_dir: Path | None, robot_name: str) -> StorageConfig:
    """Default: state in ``$XDG_STATE_HOME/payload-agent/<robot>/``, runs in its ``runs/`` (see paths)."""
    if node is None:
        node = Node({}, "storage").allow(STORAGE_KEYS)
    state_raw = node.string("state_dir", None) if node.has("state_dir") else None
    runs_raw = node.string("runs_dir", None) if node.has("runs_dir") else None
    state = resolve_against(state_raw, base_dir) if state_raw is not None else state_home()
    runs = resolve_against(runs_raw, base_dir) if runs_raw is not None else state / robot_name / "runs"
    age = node.number("baseline_max_age_days", DEFAULT_BASELINE_MAX_AGE_DAYS, gt=0, max=3650)
    dtemp = node.number("baseline_max_temperature_delta_c", DEFAULT_BASELINE_MAX_TEMPERATURE_DELTA_C, gt=0, max=100)
    node.reject_unknown()
    return StorageConfig(runs, state, age, dtemp)


def config_snapshot(config: Config) -> dict[str, Any]:
    """The raw YAML data as loaded: what goes into a run's manifest."""
    return json.loads(json.dumps(config.raw, default=str))
