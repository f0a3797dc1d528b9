"""The robot YAML's ``watch`` section: what `payload-agent watch` waits for before an unattended run."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from payload_agent.configuration.paths import resolve_against
from payload_agent.configuration.yamlcheck import Node

WATCH_TRIGGERS = ("file", "digital_input", "register")


@dataclass(frozen=True)
class WatchConfig:
    """What `payload-agent watch` waits for before an unattended run with --apply."""

    trigger: str  # "file": a file appears; "digital_input": a controller input goes high
    path: Path | None  # trigger "file"
    input_index: int | None  # trigger "digital_input": the controller's digital input number
    poll_interval_s: float


def parse_watch(node: Node, base_dir: Path | None) -> WatchConfig:
    t = node.child("trigger")
    kind = t.string("type", choices=WATCH_TRIGGERS)
    path = index = None
    if kind == "file":
        path = resolve_against(t.string("path"), base_dir)
        t.reject_unknown(["type", "path"])
    elif kind == "register":  # the driver's trigger register (modbus: the map's tool_change)
        t.reject_unknown(["type"])
    else:
        index = t.integer("index", min=0, max=255)
        t.reject_unknown(["type", "index"])
    poll = node.number("poll_interval_s", 0.5, gt=0, max=60)
    node.reject_unknown(["trigger", "poll_interval_s"])
    return WatchConfig(kind, path, index, poll)
