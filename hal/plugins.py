"""Loading plugin classes by name: a registry of names, or a ``module:Class`` path where the
caller's own configuration may name one (never a request's: that would let a client import
any module on the daemon's path)."""
from __future__ import annotations

import importlib


def load_class(name: str, registry: dict[str, str], base: type, kind: str, paths: bool = True) -> type:
    """The class ``name`` stands for in ``registry``, or (with ``paths``) at the
    ``module:Class`` path ``name``, checked to be a ``base``; LookupError with a message
    naming ``kind`` otherwise."""
    if not paths and name not in registry:
        raise LookupError(f"unknown {kind} {name!r:.80} (available: {', '.join(sorted(registry))}; a module:Class "
                          f"is made available by the daemon's own configuration, not by a request)")
    target = registry.get(name, name)
    if ":" not in target:
        raise LookupError(f"unknown {kind} {name!r:.80} (built-in: {', '.join(registry)}; or give module:Class)")
    module_name, _, class_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise LookupError(f"cannot load {kind} {target!r}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise LookupError(f"{target!r} is not a {base.__name__}")
    return cls
