"""The command catalog: every command of the protocol declared once (docs/protocol.md).

For each command: who serves it (``loop``, ``planner`` beside the loop, ``recorder``,
``messenger``), which sockets serve it, whether it needs the lease, the least role that may
send it, whether its reply is deferred, its arguments (type, bounds, unit, default), the keys
of its result and the error codes it may answer. The messenger routes by it and checks every
request's arguments against it before anything else sees them (:func:`check_args`);
handlers register against its names (:func:`check_handlers`); ``describe``, the
``unknown_command`` message, the client's deferred wait, pneumactl's help, docs/protocol.md's
command summary and docs/schemas/args.schema.json are derived from it.

The catalog checks what can be checked without the rig or the state: names, types, bounds
(of a number, a string's length and form, a list's length and each of its elements), exactly
one of a few arguments, lists whose lengths go together, the arguments each variant of a
command takes (an excite's side and signal). The messenger makes these checks, beside the
loop, whatever a request's size; what needs the rig (one angle per joint, a joint's name,
limits, reach, authority) or relates a signal's settings (a multisine's lowest frequency and
its period) or the state is the server's, after the lease and state checks.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed, bad_args
from daemon.wire.keys import OBSERVER, OPERATOR

SERVERS = ("loop", "planner", "recorder", "messenger")
BOTH = ("command", "control")
COMMAND = ("command",)
# Codes any request may get, whatever the command.
COMMON_ERRORS = (P.BAD_MESSAGE, P.BAD_VERSION, P.UNKNOWN_COMMAND, P.LOOP_STALLED, P.FORBIDDEN, P.INTERNAL)
MAX_DURATION_S = 3600.0  # the longest reference a motion command may ask for [s]
KINDS = ("number", "integer", "string", "boolean", "list", "map", "number_or_list")
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


def _record(what: str) -> Arg:
    return Arg("record", "boolean", f"record {what} on the daemon, start to end", default=False)


def _recording_name(what: str) -> Arg:
    return Arg("name", "string", f"{what}: 1-80 letters, digits, '.', '_', '-', starting with a letter or a digit",
               1, 80, pattern=RECORDING_NAME)


RECORDING_NAME = r"[A-Za-z0-9][A-Za-z0-9._-]*"  # a recording's name (its length: 1-80)
CONTROLLER_NAME = r"[A-Za-z_][A-Za-z0-9_-]*"  # a name: no path's slash, no module's dot or colon
SIGNAL_SETTINGS = {"chirp": ("f0_hz", "f1_hz", "duration_s"), "prbs": ("order", "bit_s", "periods"),
                    "multisine": ("f0_hz", "f1_hz", "components", "period_s", "periods"),
                    "steps": ("levels", "hold_s")}
_EXCITE_VARIANTS = (
    Variant("side", "reference", takes=("amplitude_deg", "amplitude_mm"),
            limits=(("signal", ("chirp", "prbs", "multisine")),)),
    Variant("side", "input", takes=("amplitude_v", "settle_s", "band_deg", "band_mm", "centre_hz"),
            requires=("amplitude_v",)),
    *(Variant("signal", signal, takes=keys) for signal, keys in SIGNAL_SETTINGS.items()))
_APPROACH = Arg("approach_s", "number", "the approach move to the start; default the shortest feasible x 1.25, "
                "at least 0.5 s", 0.0, 600.0, "s")
_BUILD = (Arg("name", "string", "a registered controller (controller.list), never a module:Class", required=True),
          Arg("params", "map", "parameter name -> a number (all joints) or a list (one per joint)"),
          Arg("options", "map", "construction options (lti/lti_dob: design)"))
_RECORDING = ("name", "file", "who", "seconds", "messages", "gaps", "bytes", "follows_reference", "ends_in_s")
_COMPARISON = ("controller", "cycles", "max_diff_volts", "rms_diff_volts")
_STATE = ("state",)
_REFUSALS = (P.BAD_STATE, P.REFUSED)

COMMANDS: dict[str, Command] = {c.name: c for c in (
    Command("ping", "loop", "is the daemon there", ("pong", "t", "version", "daemon"),
            sockets=BOTH),
    Command("status", "loop", "the daemon's state now", (
        "state", "cause", "cycle", "t", "controller", "shadow", "reference", "reference_remaining_s", "joints",
        "rig", "faults", "lease_held", "lease_holder", "unleased_disable_in_s", "client", "security", "trips",
        "overruns_total", "scheduling", "load", "transport", "telemetry", "helpers", "controllers_refused", "daemon",
        "timing", "model"),
            sockets=BOTH),
    Command("describe", "loop", "the rig, its limits and what the daemon serves", (
        "version", "protocol", "rig", "period_s", "joints", "command_interfaces", "cycle_layout", "cycle_layout_id",
        "arm", "limits", "tracking",
        "transport", "units", "controllers", "states", "commands", "control_commands", "deferred_commands",
        "deferred_timeout_s", "security")),
    Command("lease.acquire", "loop", "take the lease", ("lease", "ttl_s"), (
        Arg("ttl_s", "number", "renew within this", 0.1, 60.0, "s"),), role=OPERATOR, errors=(P.LEASE_HELD,)),
    Command("lease.renew", "loop", "renew the lease", ("ttl_s",), lease=True),
    Command("lease.release", "loop", "give the lease back", ("unleased",), lease=True),
    Command("enable", "loop", "idle -> enabled, holding the present position", ("state", "recover"), lease=True,
            errors=(P.BAD_STATE,)),
    Command("disable", "loop", "to idle, safe outputs", _STATE, sockets=BOTH, lease=True),
    Command("estop", "loop", "latch the e-stop: safe outputs this cycle", _STATE, (
        Arg("who", "string", "who stops it (first 64 characters kept)", high=64),), sockets=BOTH, strict=False),
    Command("abort", "loop", "stop any reference, hold the present position", ("reference",), sockets=BOTH),
    Command("reset", "loop", "fault/estop -> idle", _STATE, lease=True, errors=(P.BAD_STATE,)),
    Command("set", "planner", "move to joint positions or a tip point", ("target", "target_deg", "duration_s",
                                                                        "stiffness_nm_deg", "cycle", "recording"), (
        Arg("positions", "list", "one per joint, in its unit: deg on a rotary joint, mm on a linear one",
            unit="deg | mm", item=NUMBER),
        Arg("angles_deg", "list", "one angle per joint", unit="deg", item=NUMBER),
        Arg("angles_rad", "list", "one angle per joint", unit="rad", item=NUMBER),
        Arg("xy_mm", "list", "the tip [x, y]", 2, 2, "mm", item=NUMBER),
        Arg("duration_s", "number", "the cubic move's time, 0: a step", 0.0, MAX_DURATION_S, "s", 0.0),
        Arg("stiffness_nm_deg", "number_or_list", "stiffness set-point, one or one per joint (muscle joints)",
            0.0, 10.0, "N m/deg"),
        _record("the move")), lease=True, deferred=True, errors=_REFUSALS,
        one_of=("angles_deg", "angles_rad", "xy_mm", "positions")),
    Command("path", "planner", "a reference path after an approach to its start", (
        "path", "duration_s", "approach_s", "approach_chosen", "stretched_from_s", "total_s", "cycle", "recording"), (
        Arg("name", "string", "the path", required=True, choices=("translation", "circle")),
        Arg("duration_s", "number", "the path's time; default the thesis's or the shortest feasible", 0.5, MAX_DURATION_S,
            "s"),
        _APPROACH, _record("the path")), lease=True, deferred=True, errors=_REFUSALS),
    Command("waypoints", "planner", "a path through waypoints after an approach to the first", (
        "points", "duration_s", "approach_s", "approach_chosen", "total_s", "cycle", "recording"), (
        Arg("positions", "list", "joint waypoints, one position per joint each (deg rotary, mm linear)", 2, 1000,
            "deg | mm", item=NUMBERS),
        Arg("angles_deg", "list", "joint waypoints, one angle per joint each", 2, 1000, "deg", item=NUMBERS),
        Arg("xy_mm", "list", "Cartesian waypoints [x, y]", 2, 1000, "mm", item=element("list", 2, 2, item=NUMBER)),
        Arg("durations_s", "list", "one per segment, one fewer than the points (0.01-3600 s each)", 1, 999, "s",
            required=True, item=element("number", 0.01, MAX_DURATION_S, "s")),
        _APPROACH, _record("the path")), lease=True, deferred=True, errors=_REFUSALS,
        one_of=("angles_deg", "xy_mm", "positions"),
        lengths=(("durations_s", ("positions", "angles_deg", "xy_mm"), -1),)),
    Command("steps", "planner", "a step to each level in turn, held for its time", (
        "levels", "duration_s", "cycle", "recording"), (
        Arg("positions", "list", "levels, one position per joint each (deg rotary, mm linear)", 1, 1000, "deg | mm",
            item=NUMBERS),
        Arg("angles_deg", "list", "levels, one angle per joint each", 1, 1000, "deg", item=NUMBERS),
        Arg("hold_s", "list", "one per level (0.001-3600 s each)", 1, 1000, "s", required=True,
            item=element("number", 0.001, MAX_DURATION_S, "s")),
        _record("the steps")), lease=True, deferred=True, errors=_REFUSALS, one_of=("angles_deg", "positions"),
        lengths=(("hold_s", ("positions", "angles_deg"), 0),)),
    Command("excite", "planner", "an identification signal on one joint's reference or V_MV", (
        "signal", "joint", "side", "duration_s", "settle_s", "predicted_excursion_deg", "u_op_estimate_v", "cycle",
        "recording"), (
        Arg("side", "string", "the reference, or the joint's V_MV (open loop)", default="reference",
            choices=("reference", "input")),
        Arg("signal", "string", "the signal (steps: input side only)", required=True,
            choices=("chirp", "prbs", "multisine", "steps")),
        Arg("joint", "string", "the joint's name", required=True),
        Arg("amplitude_deg", "number", "reference side: the amplitude (a rotary joint: required)", 0.01, 45.0, "deg"),
        Arg("amplitude_mm", "number", "reference side: the amplitude (a linear joint: required)", 0.01, 500.0, "mm"),
        Arg("amplitude_v", "number", "input side: the amplitude", 0.01, 10.0, "V"),
        Arg("settle_s", "number", "input side: feedback holds this long first", 0.2, 60.0, "s", 2.0),
        Arg("band_deg", "number", "input side: held where it is past set-point +- this", 0.5, 45.0, "deg", 10.0),
        Arg("band_mm", "number", "input side, a linear joint: held where it is past set-point +- this", 0.5, 500.0,
            "mm", 20.0),
        Arg("centre_hz", "number", "input side: the centring PI's crossover, 0: none", 0.0, 0.2, "Hz", 0.03),
        Arg("f0_hz", "number", "chirp, multisine: the lowest frequency (multisine: at least 1/period_s)",
            0.001, 100.0, "Hz", 0.1),
        Arg("f1_hz", "number", "chirp, multisine: the highest frequency, above f0_hz", 0.001, 100.0, "Hz", 1.0),
        Arg("duration_s", "number", "chirp: its length", 1.0, MAX_DURATION_S, "s", 60.0),
        Arg("order", "integer", "prbs: register length (2^order - 1 bits)", 2, 16, default=8),
        Arg("bit_s", "number", "prbs: bit time", 0.001, 60.0, "s", 0.2),
        Arg("periods", "integer", "prbs (default 1), multisine (default 2): repetitions", 1, 100),
        Arg("components", "integer", "multisine: sines", 1, 32, default=16),
        Arg("period_s", "number", "multisine: its period", 1.0, 600.0, "s", 20.0),
        Arg("levels", "list", "steps: fractions of amplitude_v, -1..1", 1, 256, item=element("number", -1.0, 1.0)),
        Arg("hold_s", "number", "steps: each level's time", 0.01, 60.0, "s", 2.0),
        _record("the experiment")), lease=True, deferred=True, errors=_REFUSALS, variants=_EXCITE_VARIANTS),
    Command("controller.list", "loop", "the controllers this daemon can run", ("active", "available")),
    Command("controller.get", "loop", "the active controller's parameters", ("name", "params", "spec", "source")),
    Command("controller.switch", "planner", "build a controller beside the loop and swap it in",
            ("active", "params", "carried", "reset", "cycle"), _BUILD, lease=True, deferred=True,
            errors=(P.REFUSED,)),
    Command("controller.set", "planner", "change the active controller's parameters", ("name", "params", "cycle"), (
        Arg("params", "map", "parameter name -> a number (all joints) or a list (one per joint), at least one",
            1, 256, required=True),),
            lease=True, deferred=True, errors=(P.REFUSED,)),
    Command("controller.shadow", "planner", "run a candidate beside the active controller, unapplied",
            ("shadow", "active", "carried", "cycle"), _BUILD, lease=True, deferred=True, errors=(P.REFUSED,)),
    Command("controller.commit", "loop", "make the shadow candidate active", (*_COMPARISON, "active", "cycle"), (
        Arg("force", "boolean", "commit though the candidate's output was more than half a command's range "
            "(RMS) away from the active controller's in the shadow run", default=False),), lease=True,
            errors=(P.BAD_STATE, P.REFUSED)),
    Command("controller.discard", "loop", "end the shadow run", _COMPARISON, lease=True, errors=(P.BAD_STATE,)),
    Command("controller.reload", "planner", "read a controller's plugin file again, from the daemon's controller "
            "directories, check it and make its new version available", (
                "name", "file", "sha256", "previous_sha256", "unchanged", "controllers", "cycle"), (
        Arg("name", "string", "a controller from a controller directory (controller.list), or the name of a "
            "refused file there (status.controllers_refused); never a path or a module", 1, 80, required=True,
            pattern=CONTROLLER_NAME),), role=OPERATOR, deferred=True, errors=(P.REFUSED,)),
    Command("load.set", "loop", "feed a known payload forward", ("load", "cycle"), (
        Arg("mass_kg", "number", "the payload's mass", 0.0, 1000.0, "kg", required=True, above=True),
        Arg("com_mm", "list", "its centre of mass from the tip, [along, across] the last link", 2, 2, "mm",
            [0.0, 0.0], item=NUMBER)), lease=True),
    Command("load.clear", "loop", "stop feeding a load forward", ("cleared", "cycle"), lease=True),
    Command("record.start", "recorder", "the daemon records its telemetry", _RECORDING, (
        _recording_name("the file's name without .mcap"),
        Arg("seconds", "number", "end after this long; default at record.stop", 0.001, 86400.0, "s")),
            role=OPERATOR, errors=(P.BAD_STATE,)),
    Command("record.stop", "recorder", "end a recording the daemon makes", (*_RECORDING, "cause"), (
        _recording_name("which (needed when several run)"),), role=OPERATOR,
            errors=(P.BAD_STATE,)),
    Command("record.list", "recorder", "the daemon's recordings", ("directory", "feed_t", "active", "files", "more",
                                                                   "flight"), errors=(P.BAD_STATE,)),
    Command("record.snapshot", "recorder", "the flight recorder's last seconds written to a file now",
            ("name", "from_t", "to_t", "seconds"), (_recording_name("the file's name without .mcap"),),
            role=OPERATOR, errors=(P.BAD_STATE,)),
    Command("keys.reload", "messenger", "read the keys' allow-list again", (
        "allowed", "added", "removed", "changed", "problems"), role=OPERATOR, errors=(P.BAD_STATE,)),
)}

# Commands the daemon's own processes send each other through the loop's rings, never a client:
# no socket serves them (:func:`find` does not know them), and describe and the documents do not list them.
INTERNAL: dict[str, Command] = {c.name: c for c in (
    Command("lease.revoke", "loop", "a key left the allow-list or changed (the messenger, at a reload): its lease "
            "ends now", ("ended", "cause"), (
                Arg("key", "string", "the key's name", required=True),
                Arg("why", "string", "removed (off the allow-list) or changed (another key or role for the name)",
                    default="removed", choices=("removed", "changed"))), sockets=()),
    Command("timing.verdict", "loop", "the messenger's verdict on the loop's timing over the rig file's [timing] "
            "window (every stats window): kept for status, a timing event when it changes, the policy applied",
            ("degraded", "action"), (
                Arg("degraded", "boolean", "a limit is crossed", required=True),
                Arg("reasons", "list", "which: rate, overruns, step", item=element("string")),
                Arg("rate_hz", "number", "cycles a second achieved over the window", unit="Hz"),
                Arg("expected_hz", "number", "1/period", unit="Hz"),
                Arg("overruns", "integer", "deadlines missed in the window"),
                Arg("deadlines", "integer", "deadlines in the window (cycles run and missed)"),
                Arg("control_us", "number", "the control stage's median time in the last stats window (null: none)",
                    unit="us"),
                Arg("step_budget_us", "number", "the control stage's budget", unit="us"),
                Arg("window_s", "number", "the window judged", unit="s"),
                Arg("since_t", "number", "its start, the daemon's clock", unit="s"),
                Arg("t", "number", "its end, the daemon's clock", unit="s")), sockets=()),
)}

DEFERRED = tuple(sorted(name for name, c in COMMANDS.items() if c.deferred))


def served_on(socket: str) -> tuple[str, ...]:
    """The commands ``socket`` ("command" or "control") serves, sorted."""
    return tuple(sorted(name for name, c in COMMANDS.items() if socket in c.sockets))


_SERVED = {socket: served_on(socket) for socket in BOTH}


def find(cmd: str, socket: str) -> Command:
    """The catalog's entry for ``cmd`` on ``socket``, or ``unknown_command`` saying what the
    socket serves."""
    command = COMMANDS.get(cmd)
    if command is None:
        raise CommandFailed(P.UNKNOWN_COMMAND, f"unknown command {cmd[:80]!r} (the {socket} socket serves: "
                                               f"{', '.join(_SERVED[socket])})")
    if socket not in command.sockets:
        raise CommandFailed(P.UNKNOWN_COMMAND, f"{cmd!r} is not served on the {socket} socket (it serves: "
                                               f"{', '.join(_SERVED[socket])}); send it on the command socket")
    return command


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
            raise bad_args(f"'{name}' must hold {_offset(offset)} the items of {given}: {len(args[given]) + offset}, "
                           f"got {len(args[name])}", name, expected_items=len(args[given]) + offset)
    _check_variants(command, args)


def _offset(offset: int) -> str:
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


def check_handlers(servers: tuple[str, ...], handlers) -> None:
    """Start-up fails unless ``handlers`` (names) are exactly the catalog's commands served
    by ``servers`` (the internal ones included): no command without a handler, no handler
    without a command."""
    expected = {name for name, c in (*COMMANDS.items(), *INTERNAL.items()) if c.server in servers}
    missing, stray = expected - set(handlers), set(handlers) - expected
    if missing or stray:
        raise RuntimeError(f"the {'/'.join(servers)} handlers disagree with the catalog: no handler for "
                           f"{sorted(missing)}, no catalog entry for {sorted(stray)}")


def args_schema() -> dict:
    """docs/schemas/args.schema.json: each command's ``args`` as JSON Schema, every check
    :func:`check_args` makes but which lengths go together (JSON Schema cannot compare two
    lengths): those are stated in ``x-lengths`` and in the list's description."""
    defs = {}
    for c in COMMANDS.values():
        properties = {a.name: a.schema() for a in c.args}
        if not c.strict:  # never refused for its arguments: described, not constrained
            properties = {a.name: {"description": a.help()} for a in c.args}
        defs[c.name] = {"type": "object", "description": c.doc, "properties": properties,
                        "required": [a.name for a in c.args if a.required],
                        "additionalProperties": not c.strict}
        if c.one_of:
            defs[c.name]["oneOf"] = [{"required": [name]} for name in c.one_of]
        if c.variants:
            defs[c.name]["allOf"] = [_variant_schema(c, v) for v in c.variants]
        if c.lengths:
            defs[c.name]["x-lengths"] = [{"argument": name, "items_of": list(of), "offset": offset,
                                          "description": f"{name} holds {_offset(offset)} the items of "
                                                         f"{' or '.join(of)}"} for name, of, offset in c.lengths]
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": "pneumad/args.schema.json",
            "title": "pneumad command arguments (generated from daemon/wire/catalog.py)", "$defs": defs}


def _variant_schema(command: Command, variant: Variant) -> dict:
    """One variant as an if/then: when its argument has its value (or, for the default, is
    absent), the arguments the other variants take are absent, its own required are present,
    and the limits it puts on another argument's choices hold."""
    condition = {"properties": {variant.on: {"const": variant.value}}}
    if variant.value != command.arg(variant.on).default:
        condition["required"] = [variant.on]
    others = sorted({name for v in command.variants if v.on == variant.on for name in v.takes} - set(variant.takes))
    then: dict = {"properties": {name: False for name in others}}
    for name, allowed in variant.limits:
        then["properties"][name] = {"enum": list(allowed)}
    if variant.requires:
        then["required"] = list(variant.requires)
    return {"if": condition, "then": then}


def summary_table() -> str:
    """docs/protocol.md's command summary (between its catalog markers)."""
    rows = ["| cmd | served by | sockets | lease | role | deferred | args |", "|---|---|---|---|---|---|---|"]
    for c in COMMANDS.values():
        args = "; ".join(f"`{a.name}`{' (required)' if a.required else ''}: {a.kind}, {a.help()}" for a in c.args)
        if not c.strict:
            args += " (never refused for its arguments)"
        if c.one_of:
            args += f"; exactly one of {', '.join(f'`{name}`' for name in c.one_of)}"
        for name, of, offset in c.lengths:
            args += f"; `{name}` holds {_offset(offset)} the items of {' or '.join(f'`{o}`' for o in of)}"
        for v in c.variants:
            args += f"; {v.on} {v.value} takes {', '.join(f'`{t}`' for t in v.takes)}" + (
                f" (requires {', '.join(f'`{r}`' for r in v.requires)})" if v.requires else "") + "".join(
                f", `{name}` one of {', '.join(allowed)}" for name, allowed in v.limits)
        rows.append(f"| `{c.name}` | {c.server} | {', '.join(c.sockets)} | {'yes' if c.lease else ''} | {c.role} "
                    f"| {'yes' if c.deferred else ''} | {args} |")
    return "\n".join(rows)
