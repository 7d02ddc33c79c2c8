"""The command catalog: every command of the protocol declared once (docs/protocol.md).

For each command: who serves it (``loop``, ``planner`` beside the loop, ``recorder``,
``messenger``), which sockets serve it, whether it needs the lease, the least role that may
send it, whether its reply is deferred, its arguments (type, bounds, unit, default), the keys
of its result and the error codes it may answer (the declaration's shape, and the check of a
request's arguments against it, are :mod:`daemon.wire.command_spec`'s). The messenger routes by
it (:func:`find`) and checks every request's arguments against it before anything else sees
them; handlers register against its names (:func:`check_handlers`); ``describe``, the
``unknown_command`` message, the client's deferred wait, pneumactl's help, docs/protocol.md's
command summary and docs/schemas/args.schema.json (:mod:`daemon.wire.catalog_docs`) are
derived from it.
"""
from __future__ import annotations

from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed
from daemon.wire.command_spec import BOTH, NUMBER, NUMBERS, Arg, Command, Variant, element
from daemon.wire.keys import OPERATOR

MAX_DURATION_S = 3600.0  # the longest reference a motion command may ask for [s]


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
    Command("estop", "loop", "latch the e-stop: safe outputs this cycle", ("state", "written_by"), (
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


def check_handlers(servers: tuple[str, ...], handlers) -> None:
    """Start-up fails unless ``handlers`` (names) are exactly the catalog's commands served
    by ``servers`` (the internal ones included): no command without a handler, no handler
    without a command."""
    expected = {name for name, c in (*COMMANDS.items(), *INTERNAL.items()) if c.server in servers}
    missing, stray = expected - set(handlers), set(handlers) - expected
    if missing or stray:
        raise RuntimeError(f"the {'/'.join(servers)} handlers disagree with the catalog: no handler for "
                           f"{sorted(missing)}, no catalog entry for {sorted(stray)}")
