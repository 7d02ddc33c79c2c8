"""Controllers by name: the built-ins, entry points (group ``pneumad.controllers``), or ``module:Class``."""
from __future__ import annotations

import functools
import importlib
from importlib.metadata import entry_points

from controllers.base import Controller, ControllerContext

BUILTIN = {
    "pid": "controllers.pid:PID",
    "hold": "controllers.hold:Hold",
}


@functools.cache
def _installed() -> dict[str, str]:
    """Entry points, scanned once per process: the scan costs milliseconds."""
    return {ep.name: ep.value for ep in entry_points(group="pneumad.controllers")}


def available() -> dict[str, str]:
    """Every controller name this process can build, with where it comes from."""
    return {**_installed(), **BUILTIN}


def load(name: str) -> type[Controller]:
    target = available().get(name, name)
    if ":" not in target:
        raise LookupError(f"unknown controller {name!r} (available: {', '.join(available())}; or give module:Class)")
    module_name, _, class_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise LookupError(f"cannot load controller {target!r}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        raise LookupError(f"{target!r} is not a Controller")
    return cls


def build(name: str, context: ControllerContext, params: dict | None = None) -> Controller:
    """Construct and validate a controller off the loop; raises LookupError or ParamError."""
    return load(name)(context, **(params or {}))
