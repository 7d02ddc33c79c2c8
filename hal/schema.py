"""Build frozen dataclasses from TOML tables, strictly.

Every table key must be a field (a typo is an error, never silently ignored), every field
without a default must be present, and values must have the declared type. Range checks
live in each dataclass's ``__post_init__``, which raises :class:`Invalid`; the loader adds
the key path so the message reads like ``joints[1].sensor.direction: must be +1 or -1``.
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

from hal.errors import ConfigError


class Invalid(ValueError):
    """Raised by a dataclass's ``__post_init__``: which field is wrong and why."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


def require(condition: bool, key: str, message: str) -> None:
    """Raise :class:`Invalid` for ``key`` unless ``condition`` holds."""
    if not condition:
        raise Invalid(key, message)


def build(cls: type, data: Any, path: str = "") -> Any:
    """Build dataclass ``cls`` from a TOML table ``data``; errors name ``path``."""
    if not isinstance(data, dict):
        raise ConfigError(f"{path or '<top>'}: expected a table, got {_kind(data)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{_join(path, unknown[0])}: unknown key (allowed here: {', '.join(sorted(fields))})"
        )
    values = {}
    for name, field in fields.items():
        key_path = _join(path, name)
        if name in data:
            values[name] = _convert(hints[name], data[name], key_path)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{key_path}: missing required key")
    try:
        return cls(**values)
    except Invalid as exc:
        raise ConfigError(f"{_join(path, exc.key)}: {exc.message}") from None


def _convert(hint: Any, value: Any, path: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            return _convert(options[0], value, path)
        raise TypeError(f"unsupported union at {path}")
    if dataclasses.is_dataclass(hint):
        return build(hint, value, path)
    if origin is tuple:
        if not isinstance(value, list):
            raise ConfigError(f"{path}: expected an array, got {_kind(value)}")
        item = args[0]
        return tuple(_convert(item, v, f"{path}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: expected a table, got {_kind(value)}")
        return {k: _convert(args[1], v, _join(path, k)) for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {_kind(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{path}: must be finite, got {value}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected an integer, got {_kind(value)}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected true or false, got {_kind(value)}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {_kind(value)}")
        return value
    if hint is Any:
        return value
    raise TypeError(f"unsupported type {hint!r} at {path}")


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _kind(value: Any) -> str:
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return f"{type(value).__name__} {value!r}"
