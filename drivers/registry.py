"""Driver registry: YAML ``driver.type`` name -> Driver class.

Built-in drivers register themselves on import; third-party packages add theirs
through the ``payload_agent.drivers`` entry-point group.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from payload_agent.drivers.base import Driver
from payload_agent.errors import ConfigError

# name -> "module:Class" for built-ins, imported lazily so that a missing optional
# client library (ur-rtde, pymodbus) only matters for the driver that needs it.
_BUILTIN = {
    "elite_ec": "payload_agent.drivers.elite_ec:EliteECDriver",
    "ur_rtde": "payload_agent.drivers.ur_rtde:URRTDEDriver",
}

_REGISTERED: dict[str, type[Driver]] = {}


def register(cls: type[Driver]) -> type[Driver]:
    """Class decorator: make ``cls`` available under ``cls.name``."""
    if not cls.name:
        raise ValueError(f"{cls.__qualname__} has no name")
    _REGISTERED[cls.name] = cls
    return cls


def available() -> list[str]:
    names = set(_BUILTIN) | set(_REGISTERED)
    names |= {ep.name for ep in entry_points(group="payload_agent.drivers")}
    return sorted(names)


def driver_class(name: str, key_path: str = "driver.type") -> type[Driver]:
    if name in _REGISTERED:
        return _REGISTERED[name]
    target = _BUILTIN.get(name)
    if target is None:
        for ep in entry_points(group="payload_agent.drivers"):
            if ep.name == name:
                target = ep.value
                break
    if target is None:
        raise ConfigError(key_path, f"unknown driver {name!r}; available: {', '.join(available())}")
    module_name, _, cls_name = target.partition(":")
    module = importlib.import_module(module_name)  # may raise ConfigError for a missing client library
    cls = getattr(module, cls_name)
    _REGISTERED.setdefault(name, cls)
    return cls
