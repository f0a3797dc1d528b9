"""Reading YAML strictly, and small readers that pull typed values out of it naming the key path on error.

``load_yaml`` rejects duplicate keys (PyYAML lets the last value silently win, which once
changed a sweep speed) and names the key path and both lines. ``Node`` reads typed values
and, for an unknown or a missing key, suggests the closest allowed spelling ("did you mean").
"""

from __future__ import annotations

import difflib
import math
from typing import Any, Mapping, Sequence

import yaml

from payload_agent.errors import ConfigError

_MISSING = object()


class StrictSafeLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader that refuses a mapping with the same key twice (anywhere in the tree)."""

    def construct_mapping(self, node, deep=False):  # noqa: D102 (PyYAML hook)
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key!r} (first on line {seen[key] + 1})", key_node.start_mark)
                seen[key] = key_node.start_mark.line
            except TypeError:  # an unhashable key: PyYAML reports it itself below
                continue
        return super().construct_mapping(node, deep=deep)


def _duplicate_keys(node: yaml.Node, path: str, source: str | None, _seen: set[int] | None = None) -> None:
    """Walk a composed YAML tree; ConfigError naming the key path of the first duplicate key."""
    _seen = set() if _seen is None else _seen
    if id(node) in _seen:  # an alias of a node already checked (or a recursive anchor)
        return
    _seen.add(id(node))
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            key = str(key_node.value) if isinstance(key_node, yaml.ScalarNode) else None
            child = f"{path}.{key}" if path else str(key)
            if key is not None:
                if key in seen:
                    raise ConfigError(child, f"appears twice (lines {seen[key] + 1} and "
                                             f"{key_node.start_mark.line + 1}); remove one: YAML would silently "
                                             "use the last value", source)
                seen[key] = key_node.start_mark.line
            _duplicate_keys(value_node, child, source, _seen)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _duplicate_keys(item, f"{path}[{i}]", source, _seen)


def load_yaml(text: str, source: str | None = None) -> Any:
    """Parse YAML safely and strictly: no Python tags, no duplicate keys (ConfigError names the key)."""
    loader = StrictSafeLoader(text)
    try:
        try:
            node = loader.get_single_node()
        except yaml.YAMLError as exc:
            raise _yaml_error(exc, source) from None
        if node is None:
            return None
        _duplicate_keys(node, "", source)
        try:
            return loader.construct_document(node)
        except yaml.YAMLError as exc:
            raise _yaml_error(exc, source) from None
        except ValueError as exc:  # PyYAML's int() of a number with more than 4300 digits
            raise ConfigError("<file>", f"a value cannot be read: {exc}", source) from None
    finally:
        loader.dispose()


def _yaml_error(exc: yaml.YAMLError, source: str | None) -> ConfigError:
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "somewhere"
    return ConfigError("<file>", f"not valid YAML ({where}): {getattr(exc, 'problem', None) or exc}", source)


def did_you_mean(name: str, allowed: Sequence[str]) -> str | None:
    """The allowed key closest to a misspelt ``name`` (``speed_percnt`` -> ``speed_percent``), or None."""
    match = difflib.get_close_matches(str(name), [str(a) for a in allowed], n=1, cutoff=0.75)
    return match[0] if match else None


class Node:
    """A mapping in the YAML tree together with its key path, e.g. ``safety.floor_z_mm``."""

    def __init__(self, data: Any, path: str, source: str | None = None):
        if not isinstance(data, Mapping):
            raise ConfigError(path or "<top level>", f"expected a mapping, got {_kind(data)}", source)
        self.data = data
        self.path = path
        self.source = source
        self._used: set[str] = set()
        self._allowed: tuple[str, ...] = ()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, name: str, problem: str) -> ConfigError:
        return ConfigError(self.key(name), problem, self.source)

    def has(self, name: str) -> bool:
        return name in self.data

    def allow(self, names: Sequence[str]) -> "Node":
        """Declare every key this mapping may hold, before reading it: a missing key can then be
        traced to a misspelt one ("did you mean"), and ``reject_unknown()`` checks against it."""
        self._allowed = tuple(names)
        return self

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        self._used.add(name)
        if name not in self.data or self.data[name] is None:
            if name not in self.data:
                self._misspelt(name)
            if default is _MISSING:
                raise self.error(name, "is required but missing")
            return default
        return self.data[name]

    def _misspelt(self, name: str) -> None:
        """``name`` is absent: if an unknown key present looks like it, that key is the mistake."""
        allowed = getattr(self, "_allowed", None)
        if not allowed:
            return
        for other in self.data:
            if other not in allowed and did_you_mean(str(other), [name]) == name:
                raise self.error(str(other), f"unknown key; did you mean {name!r}?")

    def child(self, name: str, required: bool = True, *, keys: Sequence[str] | None = None) -> "Node | None":
        """The mapping under ``name`` (None if absent and not ``required``); ``keys``: its allowed keys."""
        if not required and name not in self.data:
            self.raw(name, None)
            return None
        node = Node(self.raw(name), self.key(name), self.source)
        return node.allow(keys) if keys is not None else node

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
        allowed_set = set(allowed) if allowed is not None else set(self._allowed or self._used)
        for name in self.data:
            if name not in allowed_set:
                guess = did_you_mean(str(name), sorted(allowed_set))
                hint = f"did you mean {guess!r}? " if guess else ""
                raise self.error(str(name), f"unknown key; {hint}expected one of: {', '.join(sorted(allowed_set))}")


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
    try:
        value = float(value)
    except OverflowError:  # a YAML integer of hundreds of digits
        raise ConfigError(key, f"expected a finite number, got an integer of about "
                               f"{int(value.bit_length() * 0.30103) + 1} digits", source) from None
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
