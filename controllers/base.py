"""The controller contract, after ros2_control's split of hardware from controllers.

A controller is built and validated off the loop, then swapped in at a cycle boundary.
``reset(state, last_output)`` initialises it from the measured state and the output in
force, so the switch is bumpless; ``step(state, reference)`` runs once per cycle and returns
the rig's command vector (:mod:`hal.actuation`): on a cylinder rig the manipulated variable per
joint, V_MV [V], the head-chamber command relative to its bias (rig-facts §1 [2-30]); on the
muscle rig each joint's two muscle pressures [Pa] (and its brake torque [N m]). A controller
declares the actuation it drives (``actuation``) and is refused on a rig whose joints declare
another. Everything else is SI (rad, rad/s, s, N m/rad).

Parameters are described (unit, bounds, doc) and are per joint. A change is validated whole
and applied whole, or refused with a message naming the parameter, the joint and the bound.
Options are what a controller is built from and keeps for its life (an LTI controller's
matrices); they are checked when it is built and cannot change while it runs.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from controllers.nominal import NominalJoint
from hal.muscle import MuscleJoint
from hal.bounds import clip as clamp  # noqa: F401  (part of the controller contract)


class ParamError(ValueError):
    """A parameter change is refused; nothing was applied. ``data``: what a client may act
    on without the message (``parameter``/``option``, ``joint``, ``low``, ``high``, ``unit``)."""

    def __init__(self, message: str, **data):
        super().__init__(message)
        self.data = data

    def __reduce__(self):  # it crosses from the planner process to the loop's
        return _param_error, (str(self), self.data)


def _param_error(message: str, data: dict) -> ParamError:
    return ParamError(message, **data)


class ActuationError(ParamError):
    """A controller built on a joint whose actuation it does not drive (``actuation``: the
    joint's); :func:`controllers.registry.build` adds the controllers that do."""

    def __init__(self, message: str, actuation: str):
        super().__init__(message)
        self.actuation = actuation


@dataclass(frozen=True)
class ParamSpec:
    name: str
    unit: str
    low: float
    high: float
    default: tuple[float, ...]  # one value per joint of the default 2-joint rig; repeated for more
    doc: str

    def describe(self) -> dict:
        return {"name": self.name, "unit": self.unit, "low": self.low, "high": self.high, "doc": self.doc}


@dataclass(frozen=True)
class SignalSpec:
    """An internal signal a controller publishes (one value per joint), e.g. SMC's sigma."""

    name: str
    unit: str
    doc: str

    def describe(self) -> dict:
        return {"name": self.name, "unit": self.unit, "doc": self.doc}


@dataclass(frozen=True)
class OptionSpec:
    """A construction option: fixed for the controller's life, checked by ``check_options``."""

    name: str
    doc: str
    required: bool = False

    def describe(self) -> dict:
        return {"name": self.name, "doc": self.doc, "required": self.required}


@dataclass(frozen=True)
class ControllerContext:
    """What a controller knows of the rig, fixed when it is built."""

    joint_names: tuple[str, ...]
    dt: float  # loop period [s]
    u_min: tuple[float, ...]  # each command's range (hal.actuation): V_MV per cylinder joint, from
    u_max: tuple[float, ...]  # the bias and the 0-10 V span [V]; a muscle pair's pressures [Pa] ...
    models: tuple[NominalJoint | None, ...] = ()  # nominal plant per joint, None where none is identified
    actuations: tuple[str, ...] = ()  # per joint: "cylinder" or "muscle_pair" (default: all cylinder)
    commands: tuple = ()  # hal.actuation.CommandInterface per command (default: one V_MV per joint)
    muscles: tuple = ()  # hal.muscle.MuscleJoint per joint, None for a cylinder joint
    axes: tuple = ()  # hal.linear_axis.AxisParams per joint, None for a joint that is not a linear axis
    defaults: Mapping[str, Mapping] | None = None  # the rig file's [controllers.NAME] tables: name -> parameters

    @classmethod
    def for_rig(cls, rig, actuation, dt: float) -> "ControllerContext":
        """The context of a configured rig: its joints, its command ranges, its nominal models."""
        return cls(tuple(j.name for j in rig.joints), dt, actuation.u_min, actuation.u_max,
                   tuple(NominalJoint.from_rig(j, rig.joint_params(j)) if j.head is not None else None
                         for j in rig.joints),
                   tuple(j.actuation for j in rig.joints), actuation.commands,
                   tuple(MuscleJoint.from_rig(rig, j) if j.muscles is not None else None for j in rig.joints),
                   tuple(j.linear_axis for j in rig.joints), rig.controllers)

    @property
    def n(self) -> int:
        return len(self.joint_names)

    @property
    def width(self) -> int:
        """How many commands a controller returns each cycle."""
        return len(self.u_min)

    def actuation_of(self, joint: int) -> str:
        return self.actuations[joint] if self.actuations else "cylinder"

    def require_models(self, who: str) -> tuple[NominalJoint, ...]:
        """The nominal models, or ParamError naming the joints that have none."""
        missing = [name for name, m in zip(self.joint_names, self.models or [None] * self.n) if m is None]
        if missing:
            raise ParamError(f"{who} needs an identified model for joint(s) {', '.join(missing)}: "
                             f"set [[joints]] model in the rig file (known: bottom, middle, top)")
        return self.models


@dataclass(slots=True)
class JointState:
    """Measured state at one cycle."""

    t: float  # [s]
    angles: Sequence[float]  # [rad]
    velocities: Sequence[float]  # [rad/s], filtered differences of the angles
    pressures: Sequence[float] = ()  # measured chamber pair per joint, flattened [Pa] (NaN: no sensor)


@dataclass(slots=True)
class Reference:
    """Desired motion at one cycle."""

    angles: Sequence[float]  # [rad]
    velocities: Sequence[float]  # [rad/s]
    accelerations: Sequence[float]  # [rad/s^2]
    stiffness: Sequence[float] = ()  # desired joint stiffness [N m/rad] where a joint takes one (NaN: default)


class Controller(ABC):
    """Subclasses set ``name`` and ``params`` (and ``options``) and implement ``reset`` and ``step``."""

    name: ClassVar[str] = ""
    actuation: ClassVar[str | None] = "cylinder"  # the joints it drives; None: any (it only holds an output)
    params: ClassVar[tuple[ParamSpec, ...]] = ()
    options: ClassVar[tuple[OptionSpec, ...]] = ()
    internals: ClassVar[tuple[SignalSpec, ...]] = ()

    def __init__(self, context: ControllerContext, options: Mapping[str, object] | None = None,
                 **values: Sequence[float] | float):
        self.context = context
        self._check_actuation(context)
        # the output range step() clamps to and its anti-windup judges saturation by [V]; a
        # wrapper that adds to the output (the disturbance observer) shifts it every cycle
        self.u_lo, self.u_hi = list(context.u_min), list(context.u_max)
        self.given_options = self._known_options(options or {})  # kept to build a twin elsewhere
        try:
            self.chosen = self.check_options(self.given_options)
        except ParamError as exc:  # the options refused as a whole: named for a client
            exc.data.setdefault("option", ", ".join(o.name for o in self.options))
            raise
        self._values = {p.name: _per_joint(p.default, context.n) for p in self.params}
        rig_defaults = (context.defaults or {}).get(self.name)
        if rig_defaults:  # the rig file's [controllers.NAME] over the class's own
            try:
                self._values = self.validate_params(rig_defaults)
            except ParamError as exc:
                raise ParamError(f"the rig file's [controllers.{self.name}]: {exc}", **exc.data) from None
        self.apply_params(self.prepare_params(values))

    def _check_actuation(self, context: ControllerContext) -> None:
        """ParamError unless every joint of the rig declares the actuation this controller drives."""
        if self.actuation is None:
            return
        for i, joint in enumerate(context.joint_names):
            kind = context.actuation_of(i)
            if kind != self.actuation:
                raise ActuationError(f"{self.name} drives {self.actuation} joints; joint {joint!r} is a {kind}", kind)

    def derive(self, values: Mapping[str, tuple[float, ...]]) -> object:
        """Constants the controller computes from a parameter set (gains, designs). Pure: it
        runs off the loop, so it may be slow (a Riccati solve); ``self.k`` holds its result."""
        return None

    def check_options(self, options: Mapping[str, object]) -> object:
        """Parse and check the construction options (ParamError if they will not do); the
        result is kept as ``self.chosen``. Runs before the parameters are derived."""
        return None

    def _known_options(self, options: Mapping[str, object]) -> Mapping[str, object]:
        if not isinstance(options, Mapping):
            raise ParamError(f"{self.name}: options must be a map")
        known = {o.name for o in self.options}
        unknown = sorted(map(str, set(options) - known))
        if unknown:
            raise ParamError(f"{self.name}: unknown option {unknown[0]!r} (known: {', '.join(sorted(known)) or 'none'})",
                             option=unknown[0], allowed=sorted(known))
        missing = [o.name for o in self.options if o.required and o.name not in options]
        if missing:
            raise ParamError(f"{self.name}: option {missing[0]!r} is required: "
                             f"{next(o.doc for o in self.options if o.name == missing[0])}", option=missing[0])
        return options

    @abstractmethod
    def reset(self, state: JointState, last_output: Sequence[float]) -> None:
        """Initialise from the measured state and the output in force (bumpless transfer)."""

    @abstractmethod
    def step(self, state: JointState, reference: Reference) -> list[float]:
        """V_MV per joint [V] for this cycle, within ``u_lo``..``u_hi``; an integrating state
        must not wind up while its joint's output sits at a limit."""

    def internal_signals(self) -> list[list[float]]:
        """This cycle's internal signals, one list per entry of ``internals`` (one value per
        joint). Read at a decimated rate (telemetry's ``internals`` topic), so it may compute."""
        return []

    def applied(self, output: Sequence[float]) -> None:
        """The output the loop applied this cycle when it was not this controller's own (a
        shadow run): controllers that model the plant's input follow it. Default: nothing."""

    # -- parameters ---------------------------------------------------------------------
    def get_params(self) -> dict[str, list[float]]:
        return {k: list(v) for k, v in self._values.items()}

    def validate_params(self, changes: Mapping[str, object]) -> dict:
        """The full parameter set after ``changes``, or :class:`ParamError`; applies nothing."""
        specs = {p.name: p for p in self.params}
        merged = dict(self._values)
        n = self.context.n
        for key, raw in changes.items():
            spec = specs.get(key)
            if spec is None:
                raise ParamError(f"{self.name}: unknown parameter {key!r} (known: {', '.join(specs) or 'none'})",
                                 parameter=key, allowed=list(specs))
            values = joint_values(raw, n)
            if len(values) != n:
                raise ParamError(f"{self.name}.{key}: expected {n} values (one per joint), got {len(values)}",
                                 parameter=key)
            checked = []
            for joint, v in zip(self.context.joint_names, values):
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ParamError(f"{self.name}.{key}[{joint}]: expected a finite number, got {v!r}", parameter=key,
                                     joint=joint)
                if not spec.low <= v <= spec.high:
                    raise ParamError(f"{self.name}.{key}[{joint}] = {v} {spec.unit} is outside "
                                     f"{spec.low}..{spec.high} {spec.unit}", parameter=key, joint=joint, low=spec.low,
                                     high=spec.high, unit=spec.unit)
                checked.append(float(v))
            merged[key] = tuple(checked)
        return merged

    def prepare_params(self, changes: Mapping[str, object]) -> tuple[dict, object]:
        """Validate a change and derive its constants, off the loop; applies nothing.
        A design that cannot be made from the values is a ParamError too."""
        values = self.validate_params(changes)
        try:
            return values, self.derive(values)
        except ParamError:
            raise
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            raise ParamError(f"{self.name}: no design for these parameters: {exc}") from None

    def apply_params(self, prepared: tuple[dict, object]) -> None:
        """Swap in what :meth:`prepare_params` returned: two assignments, at a cycle boundary."""
        self._values, self.k = prepared

    def set_params(self, changes: Mapping[str, object]) -> None:
        self.apply_params(self.prepare_params(changes))

    def p(self, name: str) -> tuple[float, ...]:
        return self._values[name]

    @classmethod
    def describe(cls) -> dict:
        lines = (cls.__dict__.get("__doc__") or "").strip().splitlines()  # its own: a base's would mislead
        return {"name": cls.name, "doc": lines[0] if lines else "",
                "params": [p.describe() for p in cls.params], "options": [o.describe() for o in cls.options],
                "internals": [s.describe() for s in cls.internals]}


def joint_values(raw, n: int) -> list:
    """A parameter as a request gives it, one value per joint: a list as it is, one number for
    all ``n`` joints."""
    return list(raw) if isinstance(raw, (list, tuple)) else [raw] * n


def _per_joint(default: tuple[float, ...], n: int) -> tuple[float, ...]:
    """Stretch a default to n joints, repeating the last value (the top joint takes the middle's)."""
    return tuple(default[min(i, len(default) - 1)] for i in range(n))


def check_output(u: Sequence[float], n: int) -> None:
    """ValueError unless ``u`` (what a controller's step returned) is n finite values."""
    if len(u) == n:
        for v in u:  # a loop, not all(...) over a generator: this runs every cycle
            if not math.isfinite(v):
                break
        else:
            return
    raise ValueError(f"returned {u!r}: expected {n} finite values")


