"""Wrist procedure files (procedures/wrist_*.yaml): the fast wrist moves that carry the payload's inertia.

Mass and centre of mass come from the slow sweeps; the inertia tensor needs the payload's
inertial torques, which are large only where a wrist joint accelerates hard. A wrist procedure
names tool orientations (the arm frame of link 3, as in the sweep procedures), the arm's
elevations while the wrist moves, and per move the wrist joint (4, 5 or 6) or joints (turned
together in one synchronised PTP move: the flange's angular acceleration, and so the inertial
torque's information per second, grows with each joint added) and each one's travel relative to
the orientation's wrist angles. Each move runs there and back; both legs are recorded,
once with the empty flange and once with the tool. Speed and acceleration are percent of the
robot's maxima, and the safety gate refuses a move above the YAML's caps by name (never slowed).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from payload_agent.configuration.procedure import PoseSpec, parse_poses
from payload_agent.configuration.yamlcheck import Node, check_numbers
from payload_agent.errors import ConfigError


@dataclass(frozen=True)
class WristMoveSpec:
    pose: str
    joints: tuple[int, ...]  # 1-based: 4, 5 and/or 6, turned together (one synchronised PTP move)
    from_deg: tuple[float, ...]  # per joint, relative to the pose's wrist angle of that joint
    to_deg: tuple[float, ...]

    @property
    def label(self) -> str:
        """``j6`` for one joint, ``j456`` for several (the move names' part)."""
        return "j" + "".join(str(j) for j in self.joints)


@dataclass(frozen=True)
class WristProcedure:
    name: str
    description: str
    speed_percent: float  # of the robot's max joint speed
    accel_percent: float  # of the robot's max joint acceleration
    elevation_deg: tuple[float, float]  # links 2 and 3 above horizontal while the wrist moves
    poses: dict[str, PoseSpec]
    moves: tuple[WristMoveSpec, ...]
    fingerprint: str


def load_wrist_procedure(name_or_path: str, key: str = "procedure.inertia") -> WristProcedure:
    """A bundled wrist procedure by name (``wrist_inertia``) or a YAML file by path."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") and path.exists():
        text, source = path.read_text(encoding="utf-8"), str(path)
    else:
        res = resources.files("payload_agent.procedures").joinpath(f"{name_or_path}.yaml")
        if not res.is_file():
            bundled = sorted(p.name[:-5] for p in resources.files("payload_agent.procedures").iterdir()
                             if p.name.startswith("wrist") and p.name.endswith(".yaml"))
            raise ConfigError(key, f"no wrist procedure {name_or_path!r}; bundled: {', '.join(bundled)}")
        text, source = res.read_text(encoding="utf-8"), f"procedures/{name_or_path}.yaml"
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError("<file>", f"not valid YAML: {exc}", source) from None
    return parse_wrist_procedure(data, source)


def parse_wrist_procedure(data, source: str = "<wrist procedure>") -> WristProcedure:
    top = Node(data, "", source)
    name = top.string("name")
    description = top.string("description", "")
    speed = top.number("speed_percent", gt=0, max=100)
    accel = top.number("accel_percent", gt=0, max=100)
    elev = top.numbers("elevation_deg", 2, min=-90, max=90)
    poses = parse_poses(top)
    if not poses:
        raise top.error("poses", "expected a mapping of pose names to {tool_x, tool_z}")
    raw = top.raw("moves")
    if not isinstance(raw, list) or not raw:
        raise top.error("moves", "expected a non-empty list of {pose, joint, range_deg}")
    moves = []
    for i, item in enumerate(raw):
        m = Node(item, f"moves[{i}]", source)
        pose = m.string("pose", choices=sorted(poses))
        moves.append(_move(m, pose))
    top.reject_unknown(["name", "description", "speed_percent", "accel_percent", "elevation_deg", "poses", "moves"])
    fp = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]
    return WristProcedure(name, description, speed, accel, (elev[0], elev[1]), poses, tuple(moves), fp)


def _move(m: Node, pose: str) -> WristMoveSpec:
    """One move: ``joint: 6, range_deg: [0, 60]``, or several wrist joints turned together in one synchronised PTP
    move, ``joint: [4, 5, 6], range_deg: [[0, 45], [0, -45], [0, 45]]`` (one range per joint, in that order)."""
    raw_j, raw_r = m.raw("joint"), m.raw("range_deg")
    several = isinstance(raw_j, list)
    joints = raw_j if several else [raw_j]
    if not joints or any(isinstance(j, bool) or j not in (4, 5, 6) for j in joints) or len(set(joints)) != len(joints):
        raise m.error("joint", f"expected a wrist joint (4, 5 or 6) or a list of different ones, got {raw_j!r}")
    if several and (not isinstance(raw_r, list) or len(raw_r) != len(joints)):
        raise m.error("range_deg", f"expected one [from, to] per joint of {joints}, got {raw_r!r}")
    ranges = []
    for k, r in enumerate(raw_r if several else [raw_r]):
        key = f"{m.key('range_deg')}[{k}]" if several else m.key("range_deg")
        lo, hi = check_numbers(r, key, 2, source=m.source, min=-360, max=360)
        if abs(hi - lo) < 20:
            raise ConfigError(key, f"needs at least 20 degrees of travel, got [{lo:g}, {hi:g}]", m.source)
        ranges.append((lo, hi))
    m.reject_unknown(["pose", "joint", "range_deg"])
    return WristMoveSpec(pose, tuple(int(j) for j in joints), tuple(r[0] for r in ranges), tuple(r[1] for r in ranges))


def inertia_procedure_key(node: Node) -> str | None:
    """``procedure.inertia``: false/absent (mass and CoM only), true (the bundled ``wrist_inertia``) or a name."""
    value = node.raw("inertia", False)
    if value is False:
        return None
    name = "wrist_inertia" if value is True else value
    if not isinstance(name, str) or not name.strip():
        raise node.error("inertia", f"expected true, false or a wrist procedure name, got {value!r}")
    try:
        load_wrist_procedure(name, node.key("inertia"))
    except ConfigError as exc:
        raise node.error("inertia", exc.problem) from None
    return name
