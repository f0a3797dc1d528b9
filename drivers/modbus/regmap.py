"""A register map: which signal lives where, read from the robot YAML or a preset plus overrides.

The signals (``SIGNALS``) are the driver's whole view of a Modbus robot: joint angles and
efforts, status, the flange/TCP pose, the handshake fields of docs/modbus.md, the payload
write-back fields and a tool-change trigger. ``build_map`` merges a preset with the YAML's
``map`` overrides (key by key; ``null`` removes an optional signal) and validates the result
before anything connects, naming the entry in every error: unknown keys, types and tables,
counts that do not fit the type or the signal, overlapping entries, signals written by the
agent in a read-only table, required signals missing.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

import yaml

from payload_agent.configuration.yamlcheck import Node
from payload_agent.drivers.modbus.registers import (BIT_TABLES, MAX_READ_BITS, MAX_READ_REGISTERS, ORDERS, TABLES,
                                                    TYPES, WRITABLE_TABLES, Entry)
from payload_agent.errors import ConfigError

EFFORT_UNITS = ("A", "Nm", "percent_rated", "permille_rated")  # the robot YAML's effort.unit choices
ROBOT, AGENT = "robot", "agent"  # who writes the signal


@dataclass(frozen=True)
class SignalSpec:
    values: int  # how many values the signal has
    writer: str  # ROBOT (the agent reads it) or AGENT (the agent writes it)
    required: bool
    units: tuple[str, ...] = ("",)  # allowed units; the first is the default ("" = a plain number)
    integer_only: bool = False  # counters and codes must be integer types
    help: str = ""


_LEN = ("m", "mm")
_ANG = ("rad", "deg")
SIGNALS: dict[str, SignalSpec] = {
    # joint state (one block read per sample where the addresses allow)
    "joint_angles": SignalSpec(6, ROBOT, True, _ANG, help="actual joint angles"),
    "joint_revolutions": SignalSpec(6, ROBOT, False, _ANG, help="full turns, as an angle added to joint_angles"),
    "joint_efforts": SignalSpec(6, ROBOT, True, EFFORT_UNITS, help="motor current or torque per joint"),
    "timestamp": SignalSpec(1, ROBOT, False, ("s",), help="controller clock of the sample"),
    # status
    "robot_mode": SignalSpec(1, ROBOT, False, integer_only=True, help="motion allowed only in ok_values"),
    "power_on": SignalSpec(1, ROBOT, False, integer_only=True, help="non-zero: arm powered"),
    "protective_stop": SignalSpec(1, ROBOT, False, integer_only=True, help="non-zero: protective stop"),
    "emergency_stop": SignalSpec(1, ROBOT, False, integer_only=True, help="non-zero: emergency stop"),
    "fault_code": SignalSpec(1, ROBOT, False, integer_only=True, help="non-zero: a fault the controller reports"),
    "firmware_major": SignalSpec(1, ROBOT, False, integer_only=True),
    "firmware_minor": SignalSpec(1, ROBOT, False, integer_only=True),
    # pose for the kinematic cross-check
    "tcp_position": SignalSpec(3, ROBOT, False, _LEN, help="TCP position x, y, z, base frame"),
    "tcp_rotation": SignalSpec(3, ROBOT, False, _ANG, help="TCP orientation as a rotation vector, base frame"),
    "tcp_offset_position": SignalSpec(3, ROBOT, False, _LEN, help="TCP offset from the flange, flange frame"),
    "tcp_offset_rotation": SignalSpec(3, ROBOT, False, _ANG, help="TCP offset rotation vector, flange frame"),
    # inputs for `watch`
    "digital_inputs": SignalSpec(1, ROBOT, False, integer_only=True, help="bit field of the digital inputs"),
    "tool_change": SignalSpec(1, ROBOT, False, integer_only=True, help="non-zero: a tool change happened"),
    # the handshake (docs/modbus.md): written by the agent ...
    "cmd_target": SignalSpec(6, AGENT, True, _ANG, help="target joint angles"),
    "cmd_speed": SignalSpec(1, AGENT, True, ("rad/s", "deg/s"), help="leading-joint speed"),
    "cmd_accel": SignalSpec(1, AGENT, True, ("rad/s2", "deg/s2"), help="leading-joint acceleration"),
    "cmd_kind": SignalSpec(1, AGENT, False, integer_only=True, help="1 move, 2 set payload"),
    "payload_mass": SignalSpec(1, AGENT, False, ("kg", "g")),
    "payload_cog": SignalSpec(3, AGENT, False, _LEN, help="centre of gravity, flange frame"),
    "stop_request": SignalSpec(1, AGENT, True, integer_only=True, help="a new value asks the program to stop"),
    "cmd_seq": SignalSpec(1, AGENT, True, integer_only=True, help="written last: starts the command"),
    # ... and answered by the robot program
    "status": SignalSpec(1, ROBOT, True, integer_only=True, help="0 idle, 1 busy, 2 done, 3 error"),
    "ack_seq": SignalSpec(1, ROBOT, True, integer_only=True, help="the command the status belongs to"),
    "error_code": SignalSpec(1, ROBOT, True, integer_only=True),
    "stop_ack": SignalSpec(1, ROBOT, True, integer_only=True, help="echo of stop_request once stopped"),
    "heartbeat": SignalSpec(1, ROBOT, False, integer_only=True, help="changes every program cycle"),
    "payload_readback_mass": SignalSpec(1, ROBOT, False, ("kg", "g")),
    "payload_readback_cog": SignalSpec(3, ROBOT, False, _LEN),
}
ENTRY_KEYS = ("table", "address", "count", "type", "word_order", "byte_order", "scale", "offset", "unit",
              "ok_values", "value_names")
# signals that only make sense together
TOGETHER = (("tcp_position", "tcp_rotation"), ("tcp_offset_position", "tcp_offset_rotation"),
            ("payload_mass", "payload_cog", "cmd_kind"), ("payload_readback_mass", "payload_readback_cog"))
SI = {"deg": 3.141592653589793 / 180.0, "mm": 1e-3, "g": 1e-3, "deg/s": 3.141592653589793 / 180.0,
      "deg/s2": 3.141592653589793 / 180.0}


@dataclass(frozen=True)
class RegisterMap:
    """A validated map: entries by signal name plus the device facts that go with it."""

    entries: Mapping[str, Entry]
    vendor: str = ""
    model: str = ""
    bridge_gaps: int = 0  # registers a read may span that no entry defines (the device answers them)
    update_hz: float | None = None  # how often the device refreshes its registers, if known
    preset: str | None = None

    def __contains__(self, name: str) -> bool:
        return name in self.entries

    def __getitem__(self, name: str) -> Entry:
        return self.entries[name]

    def get(self, name: str) -> Entry | None:
        return self.entries.get(name)

    def has_all(self, *names: str) -> bool:
        return all(n in self.entries for n in names)

    @property
    def effort_unit(self) -> str:
        return self.entries["joint_efforts"].unit


def si_factor(entry: Entry) -> float:
    """Multiply an entry's decoded value by this to get SI units (rad, m, kg, rad/s, rad/s²)."""
    return SI.get(entry.unit, 1.0)


PRESET_DIR = Path(__file__).with_name("presets")


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


@lru_cache(maxsize=None)
def _load_preset_file(name: str) -> dict[str, Any]:
    with open(PRESET_DIR / f"{name}.yaml", encoding="utf-8") as f:
        return yaml.safe_load(f)


def load_preset(name: str, key_path: str = "driver.preset", source: str | None = None) -> dict[str, Any]:
    """A preset's data (a fresh copy): vendor, model, bridge_gaps, update_hz and signals."""
    if name not in preset_names():
        raise ConfigError(key_path, f"unknown preset {name!r}; available: {', '.join(preset_names())}", source)
    return copy.deepcopy(_load_preset_file(name))


def build_map(preset: Mapping[str, Any] | None, overrides: Any, key_path: str = "driver",
              source: str | None = None, preset_name: str | None = None) -> RegisterMap:
    """The preset's signals with the YAML's ``map`` overrides merged in, validated."""
    merged: dict[str, Any] = {}
    origin: dict[str, str] = {}
    meta: dict[str, Any] = {}
    if preset is not None:
        meta = {k: v for k, v in preset.items() if k != "signals"}
        for name, data in (preset.get("signals") or {}).items():
            merged[name] = copy.deepcopy(data)
            origin[name] = f"preset {preset_name}"
    if overrides is not None:
        node = Node(overrides, f"{key_path}.map", source)
        for name, data in node.data.items():
            name = str(name)
            if name not in SIGNALS:
                raise node.error(name, f"unknown signal; known: {', '.join(SIGNALS)}")
            if data is None:
                if SIGNALS[name].required:
                    raise node.error(name, "is required and cannot be removed")
                merged.pop(name, None)
                continue
            if not isinstance(data, Mapping):
                raise node.error(name, f"expected a mapping of {', '.join(ENTRY_KEYS)}, got {data!r:.60}")
            base = merged.get(name, {}) if name in merged else {}
            merged[name] = {**base, **data}
            origin[name] = "map" if name not in origin else f"{origin[name]} + map"
    entries = {}
    for name, data in merged.items():
        where = f"{key_path}.map.{name}"
        if name not in SIGNALS:
            raise ConfigError(where, f"unknown signal in {origin[name]}", source)
        entries[name] = _parse_entry(name, data, where, source, origin[name])
    regmap = RegisterMap(entries, vendor=str(meta.get("vendor", "")), model=str(meta.get("model", "")),
                         bridge_gaps=int(meta.get("bridge_gaps", 0)),
                         update_hz=float(meta["update_hz"]) if meta.get("update_hz") else None, preset=preset_name)
    validate(regmap, key_path, source)
    return regmap


def _parse_entry(name: str, data: Any, where: str, source: str | None, origin: str) -> Entry:
    spec = SIGNALS[name]
    try:
        node = Node(data, where, source)
    except ConfigError as exc:
        raise ConfigError(where, f"{exc.problem} (from {origin})", source) from None
    table = node.string("table", choices=TABLES)
    address = node.integer("address", min=0, max=65535)
    count = node.integer("count", min=1, max=65536)
    type_name = node.string("type", "bool" if table in BIT_TABLES else None)
    if type_name not in TYPES:
        raise node.error("type", f"unknown type {type_name!r}; expected one of {', '.join(TYPES)}")
    if (table in BIT_TABLES) != (type_name == "bool"):
        raise node.error("type", f"a {table} entry must be of type "
                                 f"{'bool' if table in BIT_TABLES else 'int16, uint16, int32, uint32 or float32'}"
                                 f", got {type_name}")
    word_order = node.string("word_order", "big", choices=ORDERS)
    byte_order = node.string("byte_order", "big", choices=ORDERS)
    scale = node.number("scale", 1.0)
    if scale == 0:
        raise node.error("scale", "must not be 0")
    offset = node.number("offset", 0.0)
    if name == "joint_efforts" and node.raw("unit", None) is None:
        raise node.error("unit", f"give the effort unit ({', '.join(EFFORT_UNITS)}): it must match effort.unit")
    unit = node.raw("unit", spec.units[0])
    if unit not in spec.units:
        raise node.error("unit", f"{name} takes one of {', '.join(repr(u) for u in spec.units)}, got {unit!r}")
    ok = node.raw("ok_values", None)
    if ok is not None:
        if not isinstance(ok, list) or not ok or not all(isinstance(v, int) and not isinstance(v, bool) for v in ok):
            raise node.error("ok_values", f"expected a list of integers, got {ok!r:.60}")
        ok = tuple(ok)
    names = node.raw("value_names", None) or {}
    if not isinstance(names, Mapping) or not all(isinstance(k, int) for k in names):
        raise node.error("value_names", "expected a mapping from integer values to names")
    node.reject_unknown(list(ENTRY_KEYS))
    width = TYPES[type_name][0]
    if count % width:
        raise node.error("count", f"{count} registers do not fit type {type_name} ({width} registers per value)")
    if count // width != spec.values:
        raise node.error("count", f"{name} has {spec.values} value{'s' if spec.values > 1 else ''}: count must be "
                                  f"{spec.values * width} ({spec.values} × {type_name}), got {count}")
    if address + count > 65536:
        raise node.error("count", f"address {address} + count {count} runs past register 65535")
    limit = MAX_READ_BITS if table in BIT_TABLES else MAX_READ_REGISTERS
    if count > limit:
        raise node.error("count", f"{count} is more than one Modbus request can read ({limit})")
    if spec.integer_only and type_name == "float32":
        raise node.error("type", f"{name} is a counter or code and needs an integer type, got float32")
    if spec.writer == AGENT and table not in WRITABLE_TABLES:
        raise node.error("table", f"the agent writes {name}, but a {table} table is read-only; use holding or coil")
    return Entry(name, table, address, count, type_name, word_order, byte_order, scale, offset, unit, ok,
                 dict(names), origin)


def validate(regmap: RegisterMap, key_path: str = "driver", source: str | None = None) -> None:
    """Required signals present, signals that go together complete, no two entries sharing an address."""
    entries = regmap.entries
    missing = [n for n, s in SIGNALS.items() if s.required and n not in entries]
    if missing:
        where = f" (preset {regmap.preset} does not define them)" if regmap.preset else ""
        raise ConfigError(f"{key_path}.map", f"required signals missing{where}: {', '.join(missing)}; "
                                             f"see docs/modbus.md for what each one is", source)
    for group in TOGETHER:
        present = [n for n in group if n in entries]
        if present and len(present) != len(group):
            absent = [n for n in group if n not in entries]
            raise ConfigError(f"{key_path}.map.{present[0]}", f"{', '.join(present)} needs "
                                                              f"{', '.join(absent)} as well", source)
    for table in TABLES:
        mine = sorted((e for e in entries.values() if e.table == table), key=lambda e: e.address)
        for a, b in zip(mine, mine[1:]):
            if b.address < a.end:
                raise ConfigError(f"{key_path}.map.{b.name}", f"{b.describe()} overlaps {a.describe()}", source)
    if regmap.bridge_gaps < 0:
        raise ConfigError(f"{key_path}.bridge_gaps", "must be >= 0", source)
