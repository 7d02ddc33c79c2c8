"""Loading plugin classes by name: a registry of built-in names, or any ``module:Class`` path."""
from __future__ import annotations

import importlib


def load_class(name: str, registry: dict[str, str], base: type, kind: str) -> type:
    """The class ``name`` stands for in ``registry``, or at the ``module:Class`` path ``name``,
    checked to be a ``base``; LookupError with a message naming ``kind`` otherwise."""
    target = registry.get(name, name)
    if ":" not in target:
        raise LookupError(f"unknown {kind} {name!r} (built-in: {', '.join(registry)}; or give module:Class)")
    module_name, _, class_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise LookupError(f"cannot load {kind} {target!r}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise LookupError(f"{target!r} is not a {base.__name__}")
    return cls
