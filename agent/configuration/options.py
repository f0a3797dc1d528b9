"""Typed option dataclasses read from a YAML mapping, with errors that name the key path.

A driver (or any other plugin) declares its options as a frozen, keyword-only dataclass whose
fields carry their limits through ``option(...)``; ``parse_options`` reads a YAML mapping into
it with the same ``Node`` readers as the rest of the configuration, so ``plan`` can check a
driver section without connecting and a mistake reads ``driver.rpc_port: expected an integer``.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Mapping

from payload_agent.configuration.yamlcheck import Node, check_number
from payload_agent.errors import ConfigError

_REQUIRED = dataclasses.MISSING


def option(default: Any = _REQUIRED, *, min: float | None = None, max: float | None = None,
           gt: float | None = None, choices: tuple | None = None, length: int | None = None, help: str = "") -> Any:
    """A dataclass field with the limits ``parse_options`` enforces (``default`` omitted: required)."""
    meta = {"min": min, "max": max, "gt": gt, "choices": choices, "length": length, "help": help}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def parse_options(cls: type, data: Any, key_path: str, source: str | None = None, *,
                  ignore: tuple[str, ...] = ()) -> Any:
    """Read ``data`` (a YAML mapping) into the dataclass ``cls``; unknown keys are errors."""
    node = Node(data, key_path, source)
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    node.reject_unknown(names + list(ignore))  # a misspelt key first: "did you mean", not "x is missing"
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        has_default = f.default is not _REQUIRED or f.default_factory is not _REQUIRED  # type: ignore[misc]
        if not node.has(f.name) or node.data[f.name] is None:
            node.raw(f.name, None)  # mark as read
            if not has_default:
                raise node.error(f.name, "is required but missing" + (f" ({f.metadata['help']})"
                                                                      if f.metadata.get("help") else ""))
            continue
        values[f.name] = _convert(node, f.name, hints[f.name], f.metadata)
    return cls(**values)


def _convert(node: Node, name: str, hint: Any, meta: Mapping[str, Any]) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(node, name, inner[0], meta)
    limits = {k: meta.get(k) for k in ("min", "max", "gt")}
    if hint is bool:
        return node.boolean(name)
    if hint is int:
        value = node.integer(name, min=meta.get("min"), max=meta.get("max"))
        if meta.get("choices") and value not in meta["choices"]:
            raise node.error(name, f"must be one of {', '.join(map(str, meta['choices']))}, got {value}")
        return value
    if hint is float:
        return node.number(name, **limits)
    if hint is str:
        return node.string(name, choices=meta.get("choices"))
    if origin is tuple and args and args[-1] is Ellipsis or origin is tuple and args:
        elem = args[0]
        raw = node.raw(name)
        if not isinstance(raw, (list, tuple)):
            raise node.error(name, f"expected a list, got {raw!r:.60}")
        n = meta.get("length") or (None if args[-1] is Ellipsis else len(args))
        if n is not None and len(raw) != n:
            raise node.error(name, f"expected {n} values, got {len(raw)}")
        out = []
        for i, v in enumerate(raw):
            key = node.key(f"{name}[{i}]")
            if elem is float:
                out.append(check_number(v, key, source=node.source, **limits))
            elif elem is int:
                if isinstance(v, bool) or not isinstance(v, int):
                    raise ConfigError(key, f"expected an integer, got {v!r}", node.source)
                if (meta.get("min") is not None and v < meta["min"]) or (meta.get("max") is not None
                                                                        and v > meta["max"]):
                    raise ConfigError(key, f"must be between {meta['min']} and {meta['max']}, got {v}", node.source)
                out.append(v)
            elif elem is str:
                if not isinstance(v, str) or not v:
                    raise ConfigError(key, f"expected a non-empty string, got {v!r}", node.source)
                out.append(v)
            else:
                out.append(v)
        return tuple(out)
    if dataclasses.is_dataclass(hint):
        return parse_options(hint, node.raw(name), node.key(name), node.source)
    return node.raw(name)  # mappings and lists a plugin validates itself
