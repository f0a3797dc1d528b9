"""Driver registry: YAML ``driver.type`` name -> Driver class, and the simulated controller it names.

One table, one code path. Built-in drivers are listed in ``BUILTIN``; installed packages add
theirs through the ``payload_agent.drivers`` entry-point group, and code that is not packaged
(a test, a notebook) calls ``register``. All three land in the same table of "module:Class"
targets, imported on first use so that a missing client library (ur-rtde, pymodbus, canopen)
only matters for the driver that needs it.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any

from payload_agent.drivers.base import Driver, DriverOptions, MotionLimits, Supervision
from payload_agent.errors import ConfigError

ENTRY_POINT_GROUP = "payload_agent.drivers"

BUILTIN: dict[str, str] = {
    "canopen": "payload_agent.drivers.canopen:CANopenDriver",
    "elite_ec": "payload_agent.drivers.elite_ec:EliteECDriver",
    "ur_rtde": "payload_agent.drivers.ur_rtde:URRTDEDriver",
    "modbus": "payload_agent.drivers.modbus.driver:ModbusDriver",
}

_table: dict[str, str | type[Driver]] = {}


def _load_table() -> dict[str, str | type[Driver]]:
    if not _table:
        _table.update(BUILTIN)
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            _table.setdefault(ep.name, ep.value)
    return _table


def register(name: str, target: str | type[Driver]) -> None:
    """Make a driver available under ``name``: a Driver subclass or its "module:Class"."""
    _load_table()[name] = target


def available() -> list[str]:
    return sorted(_load_table())


def driver_class(name: str, key_path: str = "driver.type") -> type[Driver]:
    target = _load_table().get(name)
    if target is None:
        raise ConfigError(key_path, f"unknown driver {name!r}; available: {', '.join(available())}")
    if isinstance(target, str):
        cls = import_target(target)  # may raise ConfigError for a missing client library
        _table[name] = cls
        return cls
    return target


def import_target(target: str) -> Any:
    module_name, _, attr = target.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def parse_driver_options(data: Any, key_path: str = "driver", source: str | None = None) -> DriverOptions:
    """Validate a YAML ``driver`` section without connecting (``plan`` and ``run`` alike)."""
    if not isinstance(data, dict):
        raise ConfigError(key_path, f"expected a mapping with at least 'type', got {data!r:.60}", source)
    kind = data.get("type")
    if not isinstance(kind, str) or not kind:
        raise ConfigError(f"{key_path}.type", f"the driver name is required; available: {', '.join(available())}",
                          source)
    return driver_class(kind, f"{key_path}.type").parse_options(data, key_path, source)


def make_driver(options: DriverOptions, limits: MotionLimits, supervision: Supervision | None = None) -> Driver:
    return driver_class(options.type)(options, limits, supervision)


def simulator_class(name: str) -> type:
    """The simulated controller a driver names (``Driver.simulator``)."""
    cls = driver_class(name)
    if not cls.simulator:
        raise ConfigError("simulation", f"the {name} driver names no simulated controller")
    return import_target(cls.simulator)
