"""Loading plugin classes by name: a registry of names, an entry-point group, or a
``module:Class`` path where the caller's own configuration may name one (never a request's:
that would let a client import any module on the daemon's path).

Entry points are python-can's ``can.interface`` pattern: a package registers a class under a
group in its metadata (``[project.entry-points."pneumad.devices"]`` in its pyproject.toml), and
the daemon finds it by name through :func:`importlib.metadata.entry_points`, importing only
the one a rig file names, when it names it. pneumad's own built-ins are registered the same way.
"""
from __future__ import annotations

import functools
import importlib
import sys
from importlib.metadata import EntryPoint, entry_points


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
    return _checked(cls, target, base)


def installed(group: str) -> dict[str, EntryPoint]:
    """The entry points of ``group`` by name (the first of a name wins, as python-can's). The
    scan reads every installed package's metadata (a fifth of a second in a large environment),
    so it is made once per group and path: a directory put on the path is scanned anew."""
    return _scan(group, tuple(sys.path))


@functools.lru_cache(maxsize=16)
def _scan(group: str, path: tuple[str, ...]) -> dict[str, EntryPoint]:  # path: the cache's key
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=group):
        found.setdefault(ep.name, ep)
    return found


def load_entry_point(name: str, group: str, base: type, kind: str) -> type:
    """The class registered as ``name`` in the entry-point ``group``, or at the ``module:Class``
    path ``name``, checked to be a ``base``. LookupError naming ``kind`` if there is none, or
    if it fails to import (with the plugin's own error and where it comes from): a plugin's
    failure to load is a refusal, never a crash."""
    if ":" in name:
        return load_class(name, {}, base, kind)
    known = installed(group)
    ep = known.get(name)
    if ep is None:
        raise LookupError(f"unknown {kind} {name!r:.80} (installed: {', '.join(sorted(known)) or 'none'}; a {kind} of "
                          f"your own is a package with an entry point in the group {group!r}: docs/rigs.md)")
    try:
        cls = ep.load()
    except Exception as exc:  # a plugin's own import failure, whatever it is
        dist = f" from the package {ep.dist.name} {ep.dist.version}" if ep.dist is not None else ""
        raise LookupError(f"{kind} {name!r} ({ep.value}{dist}) failed to load: {type(exc).__name__}: {exc} "
                          f"(fix or reinstall that package, or name another {kind})") from None
    return _checked(cls, ep.value, base)


def _checked(cls, target: str, base: type) -> type:
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise LookupError(f"{target!r} is not a {base.__name__}")
    return cls
