"""docs/schemas/args.schema.json says what the daemon checks: for each command, requests at and
just past every bound the catalog declares (a number's, a string's length and form, a list's
length and its elements', a map's entries), of the wrong type, with an unknown argument,
without exactly one of a few, with lengths that do not go together, with an argument the
variant does not take; each sent to a served loop with the arm idle and enabled, and judged by
the schema. One the schema refuses is ``bad_args`` in both states; one it accepts is never
``bad_args``, but where the rig or a signal's settings taken together refuse it, after the
state (docs/protocol.md, "The order of checks"), and where lengths that go together differ
(``x-lengths``: JSON Schema cannot compare two lengths)."""
from __future__ import annotations

import copy
import math

import pytest

from daemon.loop.safety import State
from daemon.testing.loop import call, dealer, make_loop, ok
from daemon.wire import catalog, catalog_docs
from daemon.wire import protocol as P
from daemon.wire.command_spec import Arg, Command
from tests.schemas import schema

# What the schema cannot say, refused bad_args after the state: (command, argument) -> why
AFTER_THE_STATE = {
    **{("excite", name): "a signal's settings taken together (f1_hz above f0_hz, f0_hz and period_s, its length)"
       for name in ("f0_hz", "f1_hz", "duration_s", "order", "bit_s", "periods", "components", "period_s")},
    ("set", "stiffness_nm_deg"): "the rig: a cylinder joint takes no stiffness",
    **{("excite", name): "the rig: a rotary joint's amplitude and band are in deg"
       for name in ("amplitude_mm", "band_mm")},
    ("load.set", "mass_kg"): "the rig: a load its joints cannot carry in every posture",
    ("controller.reload", "name"): "the daemon: a controller from its controller directories (in any state)",
}
IN_ANY_STATE = {"controller.reload"}  # deferred, yet not refused for the arm's state
STATE_CHANGING = {"estop", "enable", "disable", "reset", "lease.release", "lease.acquire", "abort"}


def bases(loop) -> dict[str, list[dict]]:
    """Valid requests on the built-in 2-joint rig, from where the arm is (angles [deg])."""
    here = [round(math.degrees(q), 3) for q in loop.reference[0]]
    step = [here[0] + 1.0, here[1]]
    return {
        "lease.acquire": [{"ttl_s": 60.0}],
        "set": [{"angles_deg": here, "duration_s": 2.0}],
        "path": [{"name": "translation"}],
        "waypoints": [{"angles_deg": [here, step], "durations_s": [2.0]},
                      {"xy_mm": [[50.0, 138.0], [55.0, 138.0]], "durations_s": [2.0]}],
        "steps": [{"angles_deg": [here], "hold_s": [1.0]}],
        "excite": [{"signal": "chirp", "joint": "middle", "amplitude_deg": 0.5},
                   {"signal": "prbs", "joint": "middle", "amplitude_deg": 0.5},
                   {"signal": "multisine", "joint": "middle", "amplitude_deg": 0.5},
                   {"side": "input", "signal": "steps", "joint": "middle", "amplitude_v": 0.3, "levels": [0.5, -0.5]}],
        "controller.switch": [{"name": "pid"}],
        "controller.shadow": [{"name": "pid"}],
        "controller.set": [{"params": {"Kp": 50.0}}],
        "controller.commit": [{}],
        "controller.reload": [{"name": "pid"}],
        "load.set": [{"mass_kg": 0.1}],
        "record.start": [{"name": "a"}],
        "record.stop": [{"name": "a"}],
    }


def values(arg: Arg, base_value) -> list:
    """Values at and just past ``arg``'s bounds, of the wrong type, and for a list its
    elements' (put first in a copy of the base's list)."""
    kind = arg.kind
    if kind in ("number", "integer", "number_or_list"):
        out = ["x", True]
        if arg.low is not None:
            step = 1 if kind == "integer" else max(abs(arg.low), abs(arg.high), 1.0) * 1e-6
            out += [arg.low, arg.high, arg.low - step, arg.high + step] + ([arg.low + step] if arg.above else [])
        if kind == "integer":
            out.append(arg.low + 0.5)
        if kind == "number_or_list":
            out += [[arg.low, arg.high], [arg.high + 1.0], [], ["x"]]
        return out
    if kind == "boolean":
        return [True, False, "yes", 1]
    if kind == "string":
        out = [5, None]
        if arg.choices:
            out.append("nope")
        if arg.pattern:
            out += ["a", "a" * int(arg.high), "", "a" * (int(arg.high) + 1), "a/b", ".a", "../etc", "a b"]
        return out
    if kind == "map":
        return ["x", [1]] + ([{}] if arg.low else [])
    out = ["x", {}]  # a list
    fill = base_value[0] if base_value else 0.0
    if arg.low is not None:
        out += [[fill] * int(arg.low), [fill] * int(arg.high), [fill] * (int(arg.low) - 1), [fill] * (int(arg.high) + 1)]
    if arg.item is not None and base_value:
        for item in values(arg.item, base_value[0] if isinstance(base_value[0], list) else None):
            out.append([item, *copy.deepcopy(base_value[1:])])
    return out


def cases(command: Command, base: dict):
    """(args, what was changed) for ``base`` and every perturbation of it."""
    yield dict(base), "as it is"
    yield {**base, "nonesuch": 1}, "an unknown argument"
    for arg in command.args:
        if arg.name not in base and _variant_refuses(command, base, arg.name):
            yield {**base, arg.name: arg.default if arg.default is not None else 1}, f"{arg.name} in another variant"
            continue
        if arg.name in command.one_of and arg.name not in base:
            yield {**base, arg.name: base[next(n for n in command.one_of if n in base)]}, f"{arg.name} beside another"
            continue
        for value in values(arg, base.get(arg.name)):
            yield _keep_lengths(command, {**base, arg.name: value}, arg.name), f"{arg.name} = {value!r:.60}"
        if arg.name in base and (arg.required or arg.name in command.one_of):
            yield {k: v for k, v in base.items() if k != arg.name}, f"no {arg.name}"


def _variant_refuses(command: Command, args: dict, name: str) -> bool:
    for v in command.variants:
        shared = {n for w in command.variants if w.on == v.on for n in w.takes}
        if v.value == args.get(v.on, command.arg(v.on).default) and name in shared and name not in v.takes:
            return True
    return False


def _keep_lengths(command: Command, args: dict, changed: str) -> dict:
    """A list whose length goes with the one ``changed`` (durations_s with the waypoints) made
    to fit it: the bound of the changed one is what is tried."""
    for name, of, offset in command.lengths:
        if changed in of and isinstance(args[changed], list) and name in args:
            n = max(len(args[changed]) + offset, 0)
            args[name] = [args[name][0]] * n
    return args


def _lengths_differ(command: Command, args: dict) -> bool:
    for name, of, offset in command.lengths:
        given = next((o for o in of if o in args), None)
        if given and isinstance(args.get(name), list) and isinstance(args[given], list) and \
                len(args[name]) != len(args[given]) + offset:
            return True
    return False


@pytest.fixture(scope="module")
def served():
    loop, _, srv = make_loop(server=True)
    loop.run(100)
    yield loop, srv
    srv.close()


@pytest.mark.slow(seconds=30)
@pytest.mark.parametrize("state", ["idle", "enabled"])
def test_the_args_schema_and_the_daemon_agree_at_every_bound(served, state):
    loop, srv = served
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]

    def put_back(lease):
        lease = lease if call(loop, sock, "lease.renew", lease=lease)["ok"] else \
            ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        if loop.state in (State.FAULT, State.ESTOP):
            ok(loop, sock, "reset", lease=lease)
        if state == "enabled" and loop.state is State.IDLE:
            ok(loop, sock, "enable", lease=lease)
        if state == "idle" and loop.state is State.ENABLED:
            ok(loop, sock, "disable", lease=lease)
        ok(loop, sock, "abort")
        return lease

    lease = put_back(lease)
    try:
        disagreements, sent = exchange_every_case(loop, sock, state, lease, put_back)
    finally:
        call(loop, sock, "lease.release", lease=lease)  # for the next state's run
    assert sent > 300
    assert not disagreements, "\n".join(disagreements[:20])


def exchange_every_case(loop, sock, state: str, lease: str, put_back) -> tuple[list[str], int]:
    """Every case of every command sent; the disagreements, and how many requests were sent."""
    disagreements, sent = [], 0
    for name, command in catalog.COMMANDS.items():
        if not command.strict:  # an e-stop: its schema constrains nothing, and it is never refused for its arguments
            assert catalog_docs.args_schema()["$defs"][name]["additionalProperties"] is True
            assert all("type" not in p for p in catalog_docs.args_schema()["$defs"][name]["properties"].values())
            continue
        validator = schema("args", name)
        for base in bases(loop).get(name, [{}]):
            assert validator.is_valid(base), (name, base)
            for args, what in cases(command, base):
                valid = validator.is_valid(args)
                if valid and (not command.args or name in STATE_CHANGING):
                    continue  # covered elsewhere: it would change the state this test keeps
                reply = call(loop, sock, name, args, lease)
                sent += 1
                code = P.BAD_ARGS if not reply["ok"] and reply["error"]["code"] == P.BAD_ARGS else "other"
                argument = reply["error"].get("data", {}).get("argument") if not reply["ok"] else None
                if not valid or _lengths_differ(command, args):
                    agree = code == P.BAD_ARGS
                elif code == P.BAD_ARGS:  # valid by the schema: only what it cannot say, and only after the state
                    agree = (name, argument) in AFTER_THE_STATE and (state == "enabled" or not command.deferred
                                                                      or name in IN_ANY_STATE)
                else:
                    agree = True
                if not agree:
                    disagreements.append(f"{state} {name} ({what}): schema {'accepts' if valid else 'refuses'}, "
                                         f"daemon {reply.get('error', 'ok')}")
                if reply["ok"] or loop.state.value != state:
                    lease = put_back(lease)
            lease = put_back(lease)
    return disagreements, sent
