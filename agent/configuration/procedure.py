"""Procedure files (procedures/*.yaml): which tool orientations and which joint sweeps."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from payload_agent.errors import ConfigError
from payload_agent.configuration.yamlcheck import Node

ARM_AXES = ("arm", "-arm", "axis", "-axis", "up", "-up")


@dataclass(frozen=True)
class PoseSpec:
    name: str
    tool_x: str
    tool_z: str


@dataclass(frozen=True)
class SweepSpec:
    pose: str
    joint: int  # 1-based: 2 or 3


@dataclass(frozen=True)
class Procedure:
    name: str
    description: str
    poses: dict[str, PoseSpec]
    sweeps: tuple[SweepSpec, ...]
    fingerprint: str


def load_procedure(name_or_path: str) -> Procedure:
    """A bundled procedure by name (``paper_bd``) or a YAML file by path."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") and path.exists():
        text, source = path.read_text(encoding="utf-8"), str(path)
    else:
        res = resources.files("payload_agent.procedures").joinpath(f"{name_or_path}.yaml")
        if not res.is_file():
            bundled = sorted(p.name[:-5] for p in resources.files("payload_agent.procedures").iterdir()
                             if p.name.endswith(".yaml"))
            raise ConfigError("procedure.name", f"no procedure {name_or_path!r}; bundled: {', '.join(bundled)}")
        text, source = res.read_text(encoding="utf-8"), f"procedures/{name_or_path}.yaml"
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError("<file>", f"not valid YAML: {exc}", source) from None
    return parse_procedure(data, source)


def parse_poses(top: Node) -> dict[str, PoseSpec]:
    """A procedure file's ``poses``: each name with its tool orientation (two perpendicular arm axes)."""
    poses_node = top.child("poses")
    poses = {}
    for pose_name in poses_node.data:
        p = poses_node.child(str(pose_name))
        tx = p.string("tool_x", choices=ARM_AXES)
        tz = p.string("tool_z", choices=ARM_AXES)
        if tx.lstrip("-") == tz.lstrip("-"):
            raise p.error("tool_z", f"must be perpendicular to tool_x ({tx}), got {tz}")
        p.reject_unknown(["tool_x", "tool_z"])
        poses[str(pose_name)] = PoseSpec(str(pose_name), tx, tz)
    return poses


def parse_procedure(data, source: str = "<procedure>") -> Procedure:
    top = Node(data, "", source)
    name = top.string("name")
    description = top.string("description", "")
    poses = parse_poses(top)
    sweeps_raw = top.raw("sweeps")
    if not isinstance(sweeps_raw, list) or not sweeps_raw:
        raise top.error("sweeps", "expected a non-empty list of {pose, joint}")
    sweeps = []
    for i, item in enumerate(sweeps_raw):
        s = Node(item, f"sweeps[{i}]", source)
        pose = s.string("pose", choices=sorted(poses))
        joint = s.integer("joint", min=2, max=3)
        s.reject_unknown(["pose", "joint"])
        sweeps.append(SweepSpec(pose, joint))
    top.reject_unknown(["name", "description", "poses", "sweeps"])
    fp = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]
    return Procedure(name, description, poses, tuple(sweeps), fp)
