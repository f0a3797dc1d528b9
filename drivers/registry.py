"""Driver registry: YAML ``driver.type`` name -> its options class and its Driver class, and the
simulated controller the driver names.

One table, one code path. Built-in drivers are listed in ``BUILTIN`` with their options class and
their driver class as two "module:Class" targets, imported on first use and separately: parsing a
robot YAML imports only the options module, so ``plan`` and the YAML checks work without the
family's client library (ur-rtde, pymodbus, canopen), which matters only when a driver is built.
Installed packages add theirs through the ``payload_agent.drivers`` entry-point group (the value
names the driver class; its options come from ``Driver.options_class``), and code that is not
packaged (a test, a notebook) calls ``register``. All land in the same table.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any

from payload_agent.drivers.base import Driver
from payload_agent.drivers.settings import DriverOptions, MotionLimits, Supervision
from payload_agent.errors import ConfigError

ENTRY_POINT_GROUP = "payload_agent.drivers"

_PKG = "payload_agent.drivers"
BUILTIN: dict[str, tuple[str, str]] = {  # name: (options class, driver class)
    "canopen": (f"{_PKG}.canopen.options:CANopenOptions", f"{_PKG}.canopen.driver:CANopenDriver"),
    "elite_ec": (f"{_PKG}.elite_ec.options:EliteECOptions", f"{_PKG}.elite_ec.driver:EliteECDriver"),
    "ur_rtde": (f"{_PKG}.ur_rtde.options:URRTDEOptions", f"{_PKG}.ur_rtde.driver:URRTDEDriver"),
    "modbus": (f"{_PKG}.modbus.options:ModbusOptions", f"{_PKG}.modbus.driver:ModbusDriver"),
}

Target = str | type  # "module:Class" or the class itself
_table: dict[str, tuple[Target | None, Target]] = {}  # name: (options class or None: the driver's, driver class)


def _load_table() -> dict[str, tuple[Target | None, Target]]:
    if not _table:
        _table.update(BUILTIN)
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            _table.setdefault(ep.name, (None, ep.value))
    return _table


def register(name: str, target: str | type[Driver], options: str | type[DriverOptions] | None = None) -> None:
    """Make a driver available under ``name``: a Driver subclass or its "module:Class", and optionally its
    options class (else the driver's ``options_class``, which imports the driver to parse a YAML)."""
    _load_table()[name] = (options, target)


def available() -> list[str]:
    return sorted(_load_table())


def _entry(name: str, key_path: str) -> tuple[Target | None, Target]:
    entry = _load_table().get(name)
    if entry is None:
        raise ConfigError(key_path, f"unknown driver {name!r}; available: {', '.join(available())}")
    return entry


def driver_class(name: str, key_path: str = "driver.type") -> type[Driver]:
    options, target = _entry(name, key_path)
    if isinstance(target, str):
        target = import_target(target)  # may raise ConfigError for a missing client library
        _table[name] = (options, target)
    return target


def options_class(name: str, key_path: str = "driver.type") -> type[DriverOptions]:
    """The options class of a driver, without importing the driver (and its client library) when the
    table names it."""
    options, target = _entry(name, key_path)
    if options is None:
        return driver_class(name, key_path).options_class
    if isinstance(options, str):
        options = import_target(options)
        _table[name] = (options, target)
    return options


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
    return options_class(kind, f"{key_path}.type").parse(data, key_path, source)


def make_driver(options: DriverOptions, limits: MotionLimits, supervision: Supervision | None = None) -> Driver:
    """The driver for parsed options (its class imported now, with its client library)."""
    return driver_class(options.type)(options, limits, supervision)


def simulator_class(name: str) -> type:
    """The simulated controller a driver names (``Driver.simulator``)."""
    cls = driver_class(name)
    if not cls.simulator:
        raise ConfigError("simulation", f"the {name} driver names no simulated controller")
    return import_target(cls.simulator)
