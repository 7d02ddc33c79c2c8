"""How a command is declared (:class:`Command`, its :class:`Arg` s and :class:`Variant` s) and how
a request's arguments are checked against its declaration (:func:`check_args`); the commands
themselves are declared in :mod:`daemon.wire.catalog`.

The checks are those that need neither the rig nor the state: names, types, bounds (of a
number, a string's length and form, a list's length and each of its elements), exactly one of
a few arguments, lists whose lengths go together, the arguments each variant of a command
takes (an excite's side and signal). The messenger makes them, beside the loop, whatever a
request's size; what needs the rig (one angle per joint, a joint's name, limits, reach,
authority) or relates a signal's settings (a multisine's lowest frequency and its period) or
the state is the server's, after the lease and state checks.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from daemon.wire import protocol as P
from daemon.wire.arguments import bad_args
from daemon.wire.keys import OBSERVER

BOTH = ("command", "control")
COMMAND = ("command",)
# Codes any request may get, whatever the command.
COMMON_ERRORS = (P.BAD_MESSAGE, P.BAD_VERSION, P.UNKNOWN_COMMAND, P.LOOP_STALLED, P.FORBIDDEN, P.INTERNAL)
_JSON_TYPES = {"number": "number", "integer": "integer", "string": "string", "boolean": "boolean", "list": "array",
               "map": "object"}


@dataclass(frozen=True)
class Arg:
    """One argument: its kind, bounds (a number's value, a list's length, a string's length),
    unit and default (None: none, or required when ``required``); a list's ``item`` (each
    element, checked as an argument is), a string's ``pattern`` (its whole value), a lower
    bound that is itself refused (``above``: a mass above 0)."""

    name: str
    kind: str
    doc: str
    low: float | None = None
    high: float | None = None
    unit: str = ""
    default: object = None
    required: bool = False
    choices: tuple[str, ...] = ()
    item: Arg | None = None
    pattern: str = ""
    above: bool = False

    def help(self) -> str:
        """A line of help: what it is, its unit, bounds and default (pneumactl's help)."""
        bounds = self._bounds() if self.low is not None and self.kind in ("number", "integer", "number_or_list") else ""
        parts = [p for p in (f"[{self.unit}]" if self.unit else "", bounds,
                             f"default {self.default}" if self.default is not None else "") if p]
        return f"{self.doc} ({', '.join(parts)})" if parts else self.doc

    def _bounds(self) -> str:
        return f"above {self.low:g}, up to {self.high:g}" if self.above else f"{self.low:g}..{self.high:g}"

    def check(self, value, index: tuple[int, ...] = (), argument: str = "") -> None:
        """bad_args (naming the request's ``argument``, this one unless given, with its bounds,
        and ``index``: where the value lies in it, an element of a list) unless ``value`` fits."""
        argument = argument or self.name
        kind = self.kind
        if kind == "number_or_list":
            if isinstance(value, list):
                element("number", self.low, self.high, self.unit).check_items(value, index, argument)
                return
            kind = "number"
        if kind in ("number", "integer"):
            if isinstance(value, bool) or not isinstance(value, int if kind == "integer" else (int, float)) \
                    or not math.isfinite(value):
                raise _refusal(argument, index, f"must be a {'whole' if kind == 'integer' else 'finite'} number, got "
                                                f"{value!r:.80}", expected=kind)
            if self.low is not None and not ((self.low < value if self.above else self.low <= value)
                                             and value <= self.high):
                raise _refusal(argument, index, f"= {value} is outside {self._bounds()}"
                                                f"{' ' + self.unit if self.unit else ''}", low=self.low, high=self.high)
        elif kind == "string":
            if not isinstance(value, str):
                raise _refusal(argument, index, f"must be a string, got {value!r:.80}", expected=kind)
            if self.choices and value not in self.choices:
                raise _refusal(argument, index, f"must be one of {', '.join(self.choices)}, got {value!r:.80}",
                               allowed=list(self.choices))
            if self.low is not None and not self.low <= len(value) <= self.high or \
                    self.pattern and not re.fullmatch(self.pattern, value):
                raise _refusal(argument, index, f"must be {self.doc}, got {value!r:.80}")
        elif kind == "boolean":
            if not isinstance(value, bool):
                raise _refusal(argument, index, f"must be true or false, got {value!r:.80}", expected=kind)
        elif kind == "list":
            if not isinstance(value, list):
                raise _refusal(argument, index, f"must be a list, got {type(value).__name__}", expected=kind)
            if self.low is not None and not self.low <= len(value) <= self.high:
                count = f"{self.low:g}" if self.low == self.high else f"{self.low:g} to {self.high:g}"
                raise _refusal(argument, index, f"must hold {count} items, got {len(value)}", low=self.low,
                               high=self.high)
            if self.item is not None:
                self.item.check_items(value, index, argument)
        elif kind == "map":
            if not isinstance(value, dict):
                raise _refusal(argument, index, f"must be a map, got {type(value).__name__}", expected=kind)
            if self.low is not None and not self.low <= len(value) <= self.high:
                raise _refusal(argument, index, f"must name {self.low:g} to {self.high:g} entries, got {len(value)}",
                               low=self.low, high=self.high)

    def check_items(self, values: list, index: tuple[int, ...], argument: str) -> None:
        """Each of ``values`` checked as this element: numbers in one tight pass (a 60 KiB list
        of them, 60 000, is the messenger's to check: about 1 us each through :meth:`check`),
        and only where that finds one at fault, each again for the refusal's words."""
        if self.kind == "number" and _numbers_fit(values, self.low, self.high, self.above):
            return
        for i, v in enumerate(values):
            self.check(v, (*index, i), argument)

    def schema(self) -> dict:
        """This argument as JSON Schema (docs/schemas/args.schema.json)."""
        out = {"description": self.help()} if self.name else {}
        if self.kind == "number_or_list":
            number = {"type": "number", "minimum": self.low, "maximum": self.high}
            return {**out, "oneOf": [number, {"type": "array", "items": number}]}
        out["type"] = _JSON_TYPES[self.kind]
        if self.item is not None:
            out["items"] = self.item.schema()
        if self.choices:
            out["enum"] = list(self.choices)
        if self.pattern:
            out["pattern"] = f"^{self.pattern}$"
        if self.low is not None:
            keys = {"list": ("minItems", "maxItems"), "string": ("minLength", "maxLength"),
                    "map": ("minProperties", "maxProperties")}.get(
                self.kind, ("exclusiveMinimum" if self.above else "minimum", "maximum"))
            out[keys[0]], out[keys[1]] = self.low, self.high
        return out


def _refusal(argument: str, index: tuple[int, ...], what: str, **data):
    """bad_args for the value at ``index`` in ``argument``: its label (``hold_s[2]``) and data."""
    label = argument + "".join(f"[{i}]" for i in index)
    return bad_args(f"'{label}' {what}", argument, **({"index": list(index)} if index else {}), **data)


def _numbers_fit(values: list, low: float | None, high: float | None, above: bool) -> bool:
    """Whether each of ``values`` is a finite number (not a boolean) in low..high (none: any)."""
    for v in values:
        cls = v.__class__
        if cls is not float and cls is not int or v - v != 0:  # a NaN or an infinity: v - v is NaN
            return False
        if low is not None and not ((low < v if above else low <= v) and v <= high):
            return False
    return True


def element(kind: str, low: float | None = None, high: float | None = None, unit: str = "",
            item: Arg | None = None) -> Arg:
    """What each element of a list argument is (an Arg without a name of its own: a refusal
    names the list, and the element's ``index``)."""
    return Arg("", kind, "", low, high, unit, item=item)


NUMBER = element("number")  # any finite number
NUMBERS = element("list", item=NUMBER)  # a row of them (its length: the rig's joints)


@dataclass(frozen=True)
class Variant:
    """What an argument's value (``value`` of ``on``, or its default) brings: the arguments that
    variant ``takes`` among those the variants of ``on`` share out (any other of those is
    refused), those it ``requires``, and ``limits`` on the choices of another argument."""

    on: str
    value: str
    takes: tuple[str, ...] = ()
    requires: tuple[str, ...] = ()
    limits: tuple[tuple[str, tuple[str, ...]], ...] = ()


@dataclass(frozen=True)
class Command:
    name: str
    server: str
    doc: str
    result: tuple[str, ...]  # the result's keys (docs/schemas/results.schema.json has their types)
    args: tuple[Arg, ...] = ()
    sockets: tuple[str, ...] = COMMAND
    lease: bool = False
    role: str = OBSERVER  # the least role that may send it
    deferred: bool = False
    strict: bool = True  # unknown arguments are refused (all but estop)
    errors: tuple[str, ...] = ()  # besides COMMON_ERRORS and those its flags imply
    one_of: tuple[str, ...] = ()  # exactly one of these arguments is given
    lengths: tuple[tuple[str, tuple[str, ...], int], ...] = ()  # (list, of the list given, offset): their lengths
    variants: tuple[Variant, ...] = ()

    @property
    def error_codes(self) -> tuple[str, ...]:
        implied = ((P.BAD_ARGS,) if self.strict else ()) + ((P.NO_LEASE,) if self.lease else ()) + \
            ((P.BUSY,) if self.deferred else ())
        return tuple(dict.fromkeys((*COMMON_ERRORS, *implied, *self.errors)))

    def arg(self, name: str) -> Arg:
        return next(a for a in self.args if a.name == name)

    def default(self, name: str):
        return self.arg(name).default


def check_args(command: Command, args: dict) -> None:
    """bad_args unless ``args`` fit the catalog (names, types, bounds, list lengths and
    elements, one of, lengths that go together, a variant's arguments). In the messenger,
    beside the loop: its cost grows with the request (up to the decoder's limits: 64 KiB). An
    e-stop's arguments are never refused (:func:`lenient_args`)."""
    if not command.strict:
        return
    names = {a.name for a in command.args}
    unknown = [str(k) for k in args if k not in names]
    if unknown:
        first = sorted(unknown)[0][:80]
        raise bad_args(f"unknown argument {first!r} ({command.name} takes "
                       f"{', '.join(a.name for a in command.args) or 'none'})", first)
    for arg in command.args:
        if arg.name in args:
            arg.check(args[arg.name])
        elif arg.required:
            raise bad_args(f"'{arg.name}' is required", arg.name)
    if command.one_of and sum(name in args for name in command.one_of) != 1:
        raise bad_args(f"give exactly one of {', '.join(command.one_of)}", command.one_of[0])
    for name, of, offset in command.lengths:
        given = next((o for o in of if o in args), None)
        if given is not None and name in args and len(args[name]) != len(args[given]) + offset:
            raise bad_args(f"'{name}' must hold {offset_words(offset)} the items of {given}: {len(args[given]) + offset}, "
                           f"got {len(args[name])}", name, expected_items=len(args[given]) + offset)
    _check_variants(command, args)


def offset_words(offset: int) -> str:
    """How a list's length stands to another's, in words (``one fewer than``)."""
    return "as many as" if offset == 0 else "one fewer than" if offset == -1 else \
        f"{-offset} fewer than" if offset < 0 else f"{offset} more than"


def _check_variants(command: Command, args: dict) -> None:
    """The arguments each variant takes, requires, and the choices it leaves another argument."""
    for on in dict.fromkeys(v.on for v in command.variants):
        value = args.get(on, command.arg(on).default)
        shared_out = {name for v in command.variants if v.on == on for name in v.takes}
        variant = next((v for v in command.variants if v.on == on and v.value == value), None)
        takes = variant.takes if variant is not None else ()
        stray = sorted(name for name in args if name in shared_out and name not in takes)
        if stray:
            raise bad_args(f"unknown argument {stray[0]!r} with {on} {value} (it takes: "
                           f"{', '.join(takes) or 'none of those'})", stray[0])
        if variant is None:
            continue
        for name in variant.requires:
            if name not in args:
                raise bad_args(f"'{name}' is required with {on} {value}", name)
        for name, allowed in variant.limits:
            if args.get(name, command.arg(name).default) not in allowed:
                raise bad_args(f"'{name}' must be one of {', '.join(allowed)} with {on} {value}", name,
                               allowed=list(allowed))


def lenient_args(command: Command, args: dict) -> dict:
    """What a command that is never refused for its arguments (an e-stop) keeps of them, as the
    messenger passes them on: its own arguments only, a string cut to its ``high`` characters
    and anything else as its repr, so the loop reads a few bytes whatever was sent."""
    kept = {}
    for arg in command.args:
        if arg.name in args:
            value = args[arg.name]
            kept[arg.name] = (value if isinstance(value, str) else repr(value)[:arg.high])[:arg.high]
    return kept
