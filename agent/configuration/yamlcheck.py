"""Small readers that pull typed values out of parsed YAML and name the key path on error."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

from payload_agent.errors import ConfigError

_MISSING = object()


class Node:
    """A mapping in the YAML tree together with its key path, e.g. ``safety.floor_z_mm``."""

    def __init__(self, data: Any, path: str, source: str | None = None):
        if not isinstance(data, Mapping):
            raise ConfigError(path or "<top level>", f"expected a mapping, got {_kind(data)}", source)
        self.data = data
        self.path = path
        self.source = source
        self._used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, name: str, problem: str) -> ConfigError:
        return ConfigError(self.key(name), problem, self.source)

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        self._used.add(name)
        if name not in self.data or self.data[name] is None:
            if default is _MISSING:
                raise self.error(name, "is required but missing")
            return default
        return self.data[name]

    def child(self, name: str, required: bool = True) -> "Node | None":
        if not required and name not in self.data:
            self._used.add(name)
            return None
        return Node(self.raw(name), self.key(name), self.source)

    def number(self, name: str, default: Any = _MISSING, *, min: float | None = None, max: float | None = None,
               gt: float | None = None) -> float:
        value = self.raw(name, default)
        return check_number(value, self.key(name), min=min, max=max, gt=gt, source=self.source)

    def integer(self, name: str, default: Any = _MISSING, *, min: int | None = None, max: int | None = None) -> int:
        value = self.raw(name, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"expected an integer, got {_kind(value)} {value!r}")
        if (min is not None and value < min) or (max is not None and value > max):
            raise self.error(name, f"must be between {min} and {max}, got {value}")
        return value

    def string(self, name: str, default: Any = _MISSING, *, choices: Sequence[str] | None = None) -> str:
        value = self.raw(name, default)
        if not isinstance(value, str) or not value.strip():
            raise self.error(name, f"expected a non-empty string, got {_kind(value)} {value!r}")
        if choices is not None and value not in choices:
            raise self.error(name, f"must be one of {', '.join(map(repr, choices))}, got {value!r}")
        return value

    def boolean(self, name: str, default: Any = _MISSING) -> bool:
        value = self.raw(name, default)
        if not isinstance(value, bool):
            raise self.error(name, f"expected true or false, got {_kind(value)} {value!r}")
        return value

    def numbers(self, name: str, length: int | None = None, default: Any = _MISSING, **limits) -> tuple[float, ...]:
        value = self.raw(name, default)
        return check_numbers(value, self.key(name), length, source=self.source, **limits)

    def per_joint(self, name: str, n: int, default: Any = _MISSING, **limits) -> tuple[float, ...]:
        """A list of n numbers, or one number meaning the same for every joint."""
        value = self.raw(name, default)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value] * n
        return check_numbers(value, self.key(name), n, source=self.source, **limits)

    def reject_unknown(self, allowed: Sequence[str] | None = None) -> None:
        """Unknown keys are errors: a misspelt safety key must not silently fall back to a default."""
        allowed_set = set(allowed) if allowed is not None else self._used
        for name in self.data:
            if name not in allowed_set:
                raise self.error(str(name), f"unknown key; expected one of: {', '.join(sorted(allowed_set))}")


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    return type(value).__name__


def check_number(value: Any, key: str, *, min: float | None = None, max: float | None = None,
                 gt: float | None = None, source: str | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(key, f"expected a number, got {_kind(value)} {value!r}", source)
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(key, f"expected a finite number, got {value}", source)
    if min is not None and value < min:
        raise ConfigError(key, f"must be >= {min:g}, got {value:g}", source)
    if max is not None and value > max:
        raise ConfigError(key, f"must be <= {max:g}, got {value:g}", source)
    if gt is not None and value <= gt:
        raise ConfigError(key, f"must be > {gt:g}, got {value:g}", source)
    return value


def check_numbers(value: Any, key: str, length: int | None = None, *, source: str | None = None,
                  **limits) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)):
        raise ConfigError(key, f"expected a list of numbers, got {_kind(value)} {value!r}", source)
    if length is not None and len(value) != length:
        raise ConfigError(key, f"expected {length} numbers, got {len(value)}", source)
    return tuple(check_number(v, f"{key}[{i}]", source=source, **limits) for i, v in enumerate(value))
