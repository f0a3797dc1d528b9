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

    trigger: str  # "file": a file appears; "digital_input": a controller input goes high; "register"
    path: Path | None  # trigger "file"
    input_index: int | None  # trigger "digital_input": the controller's digital input number
    poll_interval_s: float
    # trigger "digital_input": the inputs that carry the tool number in binary, least significant bit
    # first, read when the trigger input rises (a tool changer's coded tool ID); all low: no tool named
    tool_inputs: tuple[int, ...] = ()
    # trigger "register": the register's non-zero value is the tool number (else only a flag)
    tool_from_value: bool = False


def parse_watch(node: Node, base_dir: Path | None) -> WatchConfig:
    t = node.child("trigger")
    kind = t.string("type", choices=WATCH_TRIGGERS)
    path = index = None
    tool_inputs: tuple[int, ...] = ()
    from_value = False
    if kind == "file":
        path = resolve_against(t.string("path"), base_dir)
        t.reject_unknown(["type", "path"])
    elif kind == "register":  # the driver's trigger register (modbus: the map's tool_change)
        from_value = t.boolean("tool_from_value", False)
        t.reject_unknown(["type", "tool_from_value"])
    else:
        index = t.integer("index", min=0, max=255)
        tool_inputs = _tool_inputs(t, index)
        t.reject_unknown(["type", "index", "tool_inputs"])
    poll = node.number("poll_interval_s", 0.5, gt=0, max=60)
    node.reject_unknown(["trigger", "poll_interval_s"])
    return WatchConfig(kind, path, index, poll, tool_inputs, from_value)


def _tool_inputs(t: Node, index: int) -> tuple[int, ...]:
    """``watch.trigger.tool_inputs``: 1-16 distinct input numbers, none of them the trigger input."""
    if not t.has("tool_inputs"):
        return ()
    values = t.numbers("tool_inputs", min=0, max=255)
    if not 1 <= len(values) <= 16 or any(v != int(v) for v in values):
        raise t.error("tool_inputs", f"expected 1 to 16 input numbers (integers, least significant bit first), "
                                     f"got {list(values)}")
    bits = tuple(int(v) for v in values)
    if len(set(bits)) != len(bits) or index in bits:
        raise t.error("tool_inputs", f"{list(bits)}: each input once, and not the trigger input {index}")
    return bits
