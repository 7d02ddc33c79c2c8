"""The command catalog: every command of the protocol declared once (docs/protocol.md).

For each command: who serves it (``loop``, ``planner`` beside the loop, ``recorder``,
``messenger``), which sockets serve it, whether it needs the lease, the least role that may
send it, whether its reply is deferred, its arguments (type, bounds, unit, default), the keys
of its result and the error codes it may answer. The messenger routes by it and checks every
request's arguments against it before anything else sees them (:func:`check_args`);
handlers register against its names (:func:`check_handlers`); ``describe``, the
``unknown_command`` message, the client's deferred wait, pneumactl's help, docs/protocol.md's
command summary and docs/schemas/args.schema.json are derived from it.

The catalog checks what can be checked without the rig or the state: names, types, scalar
bounds, list lengths. What needs the rig (one angle per joint, a joint's name, limits, reach,
authority) or the state is the server's, after the lease and state checks.
"""
from __future__ import annotations

import math
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
    unit and default (None: none, or required when ``required``)."""

    name: str
    kind: str
    doc: str
    low: float | None = None
    high: float | None = None
    unit: str = ""
    default: object = None
    required: bool = False
    choices: tuple[str, ...] = ()
    numbers: bool = False  # a list whose every item is a finite number (a small fixed list: the check is bounded)

    def help(self) -> str:
        """A line of help: what it is, its unit, bounds and default (pneumactl's help)."""
        bounds = f"{self.low:g}..{self.high:g}" if self.low is not None and self.kind in ("number", "integer",
                                                                                       "number_or_list") else ""
        parts = [p for p in (f"[{self.unit}]" if self.unit else "", bounds,
                             f"default {self.default}" if self.default is not None else "") if p]
        return f"{self.doc} ({', '.join(parts)})" if parts else self.doc

    def check(self, value) -> None:
        """bad_args (naming this argument, with its bounds) unless ``value`` fits."""
        kind = self.kind
        if kind == "number_or_list":
            kind = "list" if isinstance(value, list) else "number"
        if kind in ("number", "integer"):
            if isinstance(value, bool) or not isinstance(value, int if kind == "integer" else (int, float)) \
                    or not math.isfinite(value):
                raise bad_args(f"'{self.name}' must be a {'whole' if kind == 'integer' else 'finite'} number, "
                               f"got {value!r:.80}", self.name, expected=kind)
            if self.low is not None and not self.low <= value <= self.high:
                raise bad_args(f"'{self.name}' = {value} is outside {self.low:g}..{self.high:g}"
                               f"{' ' + self.unit if self.unit else ''}", self.name, low=self.low, high=self.high)
        elif kind == "string":
            if not isinstance(value, str):
                raise bad_args(f"'{self.name}' must be a string, got {value!r:.80}", self.name, expected=kind)
            if self.choices and value not in self.choices:
                raise bad_args(f"'{self.name}' must be one of {', '.join(self.choices)}, got {value!r:.80}",
                               self.name, allowed=list(self.choices))
        elif kind == "boolean":
            if not isinstance(value, bool):
                raise bad_args(f"'{self.name}' must be true or false, got {value!r:.80}", self.name, expected=kind)
        elif kind == "list":
            if not isinstance(value, list):
                raise bad_args(f"'{self.name}' must be a list, got {type(value).__name__}", self.name, expected=kind)
            if self.kind == "list" and self.low is not None and not self.low <= len(value) <= self.high:
                raise bad_args(f"'{self.name}' must hold {self.low:g} to {self.high:g} items, got {len(value)}",
                               self.name, low=self.low, high=self.high)
            if self.kind == "number_or_list" or self.numbers:
                for i, v in enumerate(value):
                    self._check_item(i, v)
        elif kind == "map":
            if not isinstance(value, dict):
                raise bad_args(f"'{self.name}' must be a map, got {type(value).__name__}", self.name, expected=kind)

    def _check_item(self, index: int, value) -> None:
        """One number of a list: finite, and for ``number_or_list`` in the argument's bounds."""
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise bad_args(f"'{self.name}[{index}]' must be a finite number, got {value!r:.80}", self.name,
                           index=[index], expected="number")
        if self.kind == "number_or_list" and not self.low <= value <= self.high:
            raise bad_args(f"'{self.name}[{index}]' = {value} is outside {self.low:g}..{self.high:g}", self.name,
                           index=[index], low=self.low, high=self.high)

    def schema(self) -> dict:
        """This argument as JSON Schema (docs/schemas/args.schema.json)."""
        if self.kind == "number_or_list":
            number = {"type": "number", "minimum": self.low, "maximum": self.high}
            return {"description": self.help(), "oneOf": [number, {"type": "array", "items": number}]}
        out = {"description": self.help(), "type": _JSON_TYPES[self.kind]}
        if self.numbers:
            out["items"] = {"type": "number"}
        if self.choices:
            out["enum"] = list(self.choices)
        if self.low is not None:
            keys = ("minItems", "maxItems") if self.kind == "list" else ("minimum", "maximum")
            out[keys[0]], out[keys[1]] = self.low, self.high
        return out


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
        "force_n", "faults", "lease_held", "lease_holder", "unleased_disable_in_s", "client", "security", "trips",
        "overruns_total", "scheduling", "load", "transport", "telemetry", "helpers", "daemon"), sockets=BOTH),
    Command("describe", "loop", "the rig, its limits and what the daemon serves", (
        "version", "protocol", "rig", "period_s", "joints", "command_interfaces", "arm", "limits", "tracking",
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
        Arg("who", "string", "who stops it (first 64 characters kept)"),), sockets=BOTH, strict=False),
    Command("abort", "loop", "stop any reference, hold the present position", ("reference",), sockets=BOTH),
    Command("reset", "loop", "fault/estop -> idle", _STATE, lease=True, errors=(P.BAD_STATE,)),
    Command("set", "planner", "move to joint angles or a tip point", ("target_deg", "duration_s", "stiffness_nm_deg",
                                                                      "cycle", "recording"), (
        Arg("angles_deg", "list", "one angle per joint", unit="deg"),
        Arg("angles_rad", "list", "one angle per joint", unit="rad"),
        Arg("xy_mm", "list", "the tip [x, y]", 2, 2, "mm", numbers=True),
        Arg("duration_s", "number", "the cubic move's time, 0: a step", 0.0, MAX_DURATION_S, "s", 0.0),
        Arg("stiffness_nm_deg", "number_or_list", "stiffness set-point, one or one per joint (muscle joints)",
            0.0, 10.0, "N m/deg"),
        _record("the move")), lease=True, deferred=True, errors=_REFUSALS),
    Command("path", "planner", "a reference path after an approach to its start", (
        "path", "duration_s", "approach_s", "approach_chosen", "stretched_from_s", "total_s", "cycle", "recording"), (
        Arg("name", "string", "the path", required=True, choices=("translation", "circle")),
        Arg("duration_s", "number", "the path's time; default the thesis's or the shortest feasible", 0.5, MAX_DURATION_S,
            "s"),
        _APPROACH, _record("the path")), lease=True, deferred=True, errors=_REFUSALS),
    Command("waypoints", "planner", "a path through waypoints after an approach to the first", (
        "points", "duration_s", "approach_s", "approach_chosen", "total_s", "cycle", "recording"), (
        Arg("angles_deg", "list", "joint waypoints, one angle per joint each", 2, 1000, "deg"),
        Arg("xy_mm", "list", "Cartesian waypoints [x, y]", 2, 1000, "mm"),
        Arg("durations_s", "list", "one per segment (0.01-3600 s each)", 1, 999, "s", required=True),
        _APPROACH, _record("the path")), lease=True, deferred=True, errors=_REFUSALS),
    Command("steps", "planner", "a step to each level in turn, held for its time", (
        "levels", "duration_s", "cycle", "recording"), (
        Arg("angles_deg", "list", "levels, one angle per joint each", 1, 1000, "deg", required=True),
        Arg("hold_s", "list", "one per level (0.001-3600 s each)", 1, 1000, "s", required=True),
        _record("the steps")), lease=True, deferred=True, errors=_REFUSALS),
    Command("excite", "planner", "an identification signal on one joint's reference or V_MV", (
        "signal", "joint", "side", "duration_s", "settle_s", "predicted_excursion_deg", "u_op_estimate_v", "cycle",
        "recording"), (
        Arg("side", "string", "the reference, or the joint's V_MV (open loop)", default="reference",
            choices=("reference", "input")),
        Arg("signal", "string", "the signal (steps: input side only)", required=True,
            choices=("chirp", "prbs", "multisine", "steps")),
        Arg("joint", "string", "the joint's name", required=True),
        Arg("amplitude_deg", "number", "reference side: the amplitude", 0.01, 45.0, "deg"),
        Arg("amplitude_v", "number", "input side: the amplitude", 0.01, 10.0, "V"),
        Arg("settle_s", "number", "input side: feedback holds this long first", 0.2, 60.0, "s", 2.0),
        Arg("band_deg", "number", "input side: held where it is past set-point +- this", 0.5, 45.0, "deg", 10.0),
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
        Arg("levels", "list", "steps: fractions of amplitude_v, -1..1", 1, 256),
        Arg("hold_s", "number", "steps: each level's time", 0.01, 60.0, "s", 2.0),
        _record("the experiment")), lease=True, deferred=True, errors=_REFUSALS),
    Command("controller.list", "loop", "the controllers this daemon can run", ("active", "available")),
    Command("controller.get", "loop", "the active controller's parameters", ("name", "params", "spec")),
    Command("controller.switch", "planner", "build a controller beside the loop and swap it in",
            ("active", "params", "carried", "reset", "cycle"), _BUILD, lease=True, deferred=True,
            errors=(P.REFUSED,)),
    Command("controller.set", "planner", "change the active controller's parameters", ("name", "params", "cycle"), (
        Arg("params", "map", "parameter name -> a number (all joints) or a list (one per joint)", required=True),),
            lease=True, deferred=True, errors=(P.REFUSED,)),
    Command("controller.shadow", "planner", "run a candidate beside the active controller, unapplied",
            ("shadow", "active", "carried", "cycle"), _BUILD, lease=True, deferred=True, errors=(P.REFUSED,)),
    Command("controller.commit", "loop", "make the shadow candidate active", (*_COMPARISON, "active", "cycle"), (
        Arg("force", "boolean", "commit though the candidate's output was more than half a command's range "
            "(RMS) away from the active controller's in the shadow run", default=False),), lease=True,
            errors=(P.BAD_STATE, P.REFUSED)),
    Command("controller.discard", "loop", "end the shadow run", _COMPARISON, lease=True, errors=(P.BAD_STATE,)),
    Command("load.set", "loop", "feed a known payload forward", ("load", "cycle"), (
        Arg("mass_kg", "number", "the payload's mass", 0.0, 1000.0, "kg", required=True),
        Arg("com_mm", "list", "its centre of mass from the tip, [along, across] the last link", 2, 2, "mm",
            [0.0, 0.0], numbers=True)), lease=True),
    Command("load.clear", "loop", "stop feeding a load forward", ("cleared", "cycle"), lease=True),
    Command("record.start", "recorder", "the daemon records its telemetry", _RECORDING, (
        Arg("name", "string", "the file's name without .mcap (1-80 letters, digits, '.', '_', '-')"),
        Arg("seconds", "number", "end after this long; default at record.stop", 0.001, 86400.0, "s")),
            role=OPERATOR, errors=(P.BAD_STATE,)),
    Command("record.stop", "recorder", "end a recording the daemon makes", (*_RECORDING, "cause"), (
        Arg("name", "string", "which (needed when several run)"),), role=OPERATOR,
            errors=(P.BAD_STATE,)),
    Command("record.list", "recorder", "the daemon's recordings", ("directory", "feed_t", "active", "files", "more"),
            errors=(P.BAD_STATE,)),
    Command("keys.reload", "messenger", "read the keys' allow-list again", (
        "allowed", "added", "removed", "problems"), role=OPERATOR, errors=(P.BAD_STATE,)),
)}

# Commands the daemon's own processes send each other through the loop's rings, never a client:
# no socket serves them (:func:`find` does not know them), and describe and the documents do not list them.
INTERNAL: dict[str, Command] = {c.name: c for c in (
    Command("lease.revoke", "loop", "a key left the allow-list (the messenger, at a reload): its lease ends now",
            ("ended", "cause"), (Arg("key", "string", "the removed key's name", required=True),), sockets=()),
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
    """bad_args unless ``args`` fit the catalog (names, types, bounds, list lengths); its
    cost is bounded by the decoder's limits (a map of at most 256 keys). An e-stop's
    arguments are never refused."""
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
    """docs/schemas/args.schema.json: each command's ``args`` as JSON Schema."""
    defs = {}
    for c in COMMANDS.values():
        defs[c.name] = {"type": "object", "description": c.doc,
                        "properties": {a.name: a.schema() for a in c.args},
                        "required": [a.name for a in c.args if a.required],
                        "additionalProperties": not c.strict}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": "pneumad/args.schema.json",
            "title": "pneumad command arguments (generated from daemon/wire/catalog.py)", "$defs": defs}


def summary_table() -> str:
    """docs/protocol.md's command summary (between its catalog markers)."""
    rows = ["| cmd | served by | sockets | lease | role | deferred | args |", "|---|---|---|---|---|---|---|"]
    for c in COMMANDS.values():
        args = "; ".join(f"`{a.name}`{' (required)' if a.required else ''}: {a.kind}, {a.help()}" for a in c.args)
        if not c.strict:
            args += " (never refused for its arguments)"
        rows.append(f"| `{c.name}` | {c.server} | {', '.join(c.sockets)} | {'yes' if c.lease else ''} | {c.role} "
                    f"| {'yes' if c.deferred else ''} | {args} |")
    return "\n".join(rows)
