"""Controllers by name: the built-ins, entry points (group ``pneumad.controllers``), plugins the
daemon's configuration names (``pneumad --controller-plugin NAME=module:Class``), or, for the
daemon's own start-up choice only, a ``module:Class`` path. A request names a registered
controller: it never chooses a module to import."""
from __future__ import annotations

import functools
from importlib.metadata import entry_points

from controllers.base import ActuationError, Controller, ControllerContext, ParamError
from hal.plugins import load_class

BUILTIN = {
    "smc": "controllers.smc:SMC",
    "sac": "controllers.sac:SAC",
    "smc_dob": "controllers.smc:SMCWithDOB",
    "lti": "controllers.lti:LTI",
    "lti_dob": "controllers.lti:LTIWithDOB",
    "pid": "controllers.pid:PID",
    "hold": "controllers.hold:Hold",
    "muscle_eq": "controllers.muscle:MuscleEquilibrium",
    "muscle_pid": "controllers.muscle:MusclePID",
    "axis_pid": "controllers.axis:AxisPID",
    "axis_pva": "controllers.axis:AxisPVA",
}


@functools.cache
def _installed() -> dict[str, str]:
    """Entry points, scanned once per process: the scan costs milliseconds."""
    return {ep.name: ep.value for ep in entry_points(group="pneumad.controllers")}


def available(plugins: dict[str, str] | None = None) -> dict[str, str]:
    """Every controller name this process can build, with where it comes from; ``plugins``
    are the ones the daemon's configuration adds (name -> module:Class)."""
    return {**_installed(), **(plugins or {}), **BUILTIN}


def load(name: str, plugins: dict[str, str] | None = None, paths: bool = True) -> type[Controller]:
    """The controller class for a registered name, or (``paths``: the daemon's own
    configuration, never a request) a ``module:Class`` path."""
    return load_class(name, available(plugins), Controller, "controller", paths)


def build(name: str, context: ControllerContext, params: dict | None = None, options: dict | None = None,
          plugins: dict[str, str] | None = None, paths: bool = True) -> Controller:
    """Construct and validate a controller off the loop; raises LookupError or ParamError
    (on a joint it does not drive, naming the controllers that do)."""
    cls = load(name, plugins, paths)
    try:
        return cls(context, options=options, **(params or {}))
    except ActuationError as exc:
        raise ParamError(f"{exc} (controllers for it: {', '.join(drivers(exc.actuation))})") from None


def drivers(actuation: str) -> list[str]:
    """The built-in controllers that drive joints of this actuation."""
    return [name for name in BUILTIN if load(name).actuation in (actuation, None)]


def check_defaults(context: ControllerContext, plugins: dict[str, str] | None = None) -> None:
    """The rig file's ``[controllers.NAME]`` tables (``context.defaults``): ParamError naming the
    table and key unless NAME is a registered controller and every key one of its parameters;
    where the controller drives this rig, its values are checked by building it."""
    for name, table in (context.defaults or {}).items():
        try:
            cls = load(name, plugins, paths=False)
        except LookupError as exc:
            raise ParamError(f"controllers.{name}: {exc}") from None
        known = [p.name for p in cls.params]
        for key in table:
            if key not in known:
                raise ParamError(f"controllers.{name}.{key}: unknown parameter of {name} (known: "
                                 f"{', '.join(known) or 'none'})", parameter=key, allowed=known)
        try:
            cls(context)
        except ActuationError:
            continue  # a controller for other joints: its names checked, its values when a rig it drives takes them


def prepare_change(cls: type[Controller], context: ControllerContext, options: dict,
                   values: dict, changes: dict) -> tuple[dict, object]:
    """A parameter change for a running controller, prepared in another process: a twin built
    from the same class, context, options and current values derives it (derive is pure)."""
    return cls(context, options=options, **values).prepare_params(changes)
