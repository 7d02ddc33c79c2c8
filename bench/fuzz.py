"""A protocol fuzzer: malformed and hostile frames at a real daemon's command and control
sockets, counting what must never happen.

Usage: python -m bench.fuzz [--frames 100000] [--seed 1] [--idle-half] [--flood] [--no-rt]

Frames (seeded, reproducible): random bytes; valid requests cut short; envelopes with every
field missing, of the wrong type or out of range; deep nesting and huge declared lengths;
and structure-aware ones: each command's valid arguments (bench/command_cases.py) with one
argument replaced by NaN, inf, a huge or negative number, a bool, a string (unicode, binary),
a list, a map, null or a deep nest, deleted, or joined by an unknown one. The client holds
the lease, so lease-gated commands reach their argument checks.

Counted, goal zero each: a daemon that died; a frame with no reply (a hang: 40 s is the
longest a deferred reply may take); an ``internal`` reply; an error code docs/protocol.md
does not list; a rejected frame that changed the arm's state, reference or controller; a
trip no accepted frame explains. Overruns are counted against a quiet baseline of the same
length (the VM's own stalls), and so is the loop's command stage (the longest, and the
99.9th percentile of the worst window: what answering the frames costs the loop). Accepted
frames are counted too (the fuzzer does find valid commands) and the daemon is put back in its
enabled, holding state after each (``--idle-half``: the first half of the frames with the arm
idle, put back there). ``--flood`` sends the frames without waiting for their replies
(ZeroMQ drops what is beyond its queues, as documented: counted under "no reply").
"""
from __future__ import annotations

import argparse
import math
import random
import time
from dataclasses import dataclass, field

import msgpack
import zmq

from bench.command_cases import CASES
from bench.common import header, spawn_daemon, stats_subscriber
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import protocol as P
from daemon.client.client import Client, RemoteError

HOSTILE_VALUES = [math.nan, math.inf, -math.inf, 1e308, -1e308, 2 ** 63 - 1, -(2 ** 63), 0, -1, True, False, None,
                  "", "x" * 5000, "\u202e\ud7ff\U0001f600", b"\x00\xff" * 100, [], [1] * 4000, {}, {"a": {"b": {}}},
                  [[[[[[[[[[]]]]]]]]]], 1.5, "nan", "1e309"]
COMMANDS = sorted({c.cmd for c in CASES} | {"lease.release", "lease.acquire"})


@dataclass
class Tally:
    frames: int = 0
    replies: int = 0
    accepted: int = 0
    no_reply: int = 0
    internal: int = 0
    undocumented: int = 0
    changed_by_rejected: int = 0
    unexplained_trips: int = 0
    codes: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)

    def bad(self, what: str, frame: bytes) -> None:
        if len(self.examples) < 10:
            self.examples.append(f"{what}: {frame[:120]!r}")


class Frames:
    """Seeded hostile frames."""

    def __init__(self, seed: int, lease: str):
        self.rng = random.Random(seed)
        self.lease = lease
        self.valid = [(c.cmd, c.args) for c in CASES]

    def next(self) -> tuple[bytes, bool]:
        """A frame and whether it goes to the control socket."""
        kind = self.rng.random()
        control = self.rng.random() < 0.15
        if kind < 0.1:
            return bytes(self.rng.getrandbits(8) for _ in range(self.rng.randrange(0, 300))), control
        if kind < 0.2:
            frame = self._request(*self.rng.choice(self.valid))
            return frame[:self.rng.randrange(0, len(frame))], control
        if kind < 0.4:
            return self._bad_envelope(), control
        if kind < 0.45:
            return self._declared_huge(), control
        return self._request(*self._mutated_args()), control

    def _request(self, cmd, args) -> bytes:
        return msgpack.packb({"v": 1, "id": self.rng.randrange(1 << 30), "cmd": cmd, "args": args,
                              "lease": self.lease})

    def _bad_envelope(self) -> bytes:
        env = {"v": 1, "id": self.rng.randrange(1 << 30), "cmd": self.rng.choice(COMMANDS), "args": {},
               "lease": self.lease}
        key = self.rng.choice(["v", "id", "cmd", "args", "lease", "extra"])
        if self.rng.random() < 0.3:
            env.pop(key, None)
        else:
            env[key] = self.rng.choice(HOSTILE_VALUES)
        if self.rng.random() < 0.1:
            return msgpack.packb([env])
        return msgpack.packb(env)

    def _declared_huge(self) -> bytes:
        """A map, array, string or binary header declaring 2^32 - 1 items or bytes, then little."""
        return self.rng.choice([b"\xdf", b"\xdd", b"\xdb", b"\xc6"]) + b"\xff\xff\xff\xff" + b"\x00" * 8

    def _mutated_args(self) -> tuple[str, dict]:
        cmd, args = self.rng.choice(self.valid)
        args = dict(args)
        keys = list(args)
        roll = self.rng.random()
        if keys and roll < 0.6:
            key = self.rng.choice(keys)
            value = args[key]
            if isinstance(value, list) and value and self.rng.random() < 0.5:  # one element of a list
                value = list(value)
                i = self.rng.randrange(len(value))
                inner = value[i]
                if isinstance(inner, list) and inner:
                    inner = list(inner)
                    inner[self.rng.randrange(len(inner))] = self.rng.choice(HOSTILE_VALUES)
                    value[i] = inner
                else:
                    value[i] = self.rng.choice(HOSTILE_VALUES)
                args[key] = value
            else:
                args[key] = self.rng.choice(HOSTILE_VALUES)
        elif keys and roll < 0.75:
            del args[self.rng.choice(keys)]
        else:
            args[self.rng.choice(["x", "", "\u0000", "duration_s", "name", "params"])] = self.rng.choice(HOSTILE_VALUES)
        return cmd, args


def _sockets(eps: dict[str, str], ctx: zmq.Context) -> dict[str, zmq.Socket]:
    socks = {}
    for name in ("command", "control"):
        socks[name] = ctx.socket(zmq.DEALER)
        socks[name].setsockopt(zmq.LINGER, 0)
        socks[name].connect(eps[name])
    return socks


def status_key(status: dict) -> tuple:
    return status["state"], status["reference"], status["controller"]


def restore(client: Client, state: str = "enabled") -> dict:
    """Back to ``state`` (enabled, holding; or idle), PID, no load, with the lease (a fuzzed
    lease.release is a valid command): the state rejected frames must not change."""
    status = client.status()
    if status["lease_held"] and client.lease is not None:
        try:
            client.renew_lease()
        except RemoteError:  # a fuzzed lease.acquire took it (a flood's): it lapses within its ttl (60 s at most)
            deadline = time.monotonic() + 70.0
            while client.status()["lease_held"] and time.monotonic() < deadline:
                time.sleep(0.5)
            status = client.status()
    if not status["lease_held"]:
        client.lease = None
        client.acquire_lease(ttl_s=60.0)
    if status["state"] in ("fault", "estop"):
        client.reset()
    now = client.status()["state"]
    if now == "idle" and state == "enabled":
        client.enable()
    elif now == "enabled" and state == "idle":
        client.disable()
    client.abort()
    if status["load"] is not None:
        client.call("load.clear")
    if client.controller()["name"] != "pid":
        client.switch_controller("pid")
    try:
        client.discard()
    except RemoteError:
        pass
    return client.status()


def fuzz(eps: dict[str, str], frames: int, seed: int, state: str = "enabled") -> Tally:
    """``frames`` seeded frames, one at a time, each reply awaited, the arm kept in ``state``."""
    client = Client(**eps, timeout=10.0)
    client.acquire_lease(ttl_s=60.0)
    client.keep_lease(1.0)
    socks = _sockets(eps, zmq.Context.instance())
    tally = Tally()
    try:
        before = restore(client, state)
        gen = Frames(seed, client.lease)
        for _ in range(frames):
            frame, control = gen.next()
            sock = socks["control" if control else "command"]
            sock.send(frame)
            tally.frames += 1
            if not sock.poll(40_000):
                tally.no_reply += 1
                tally.bad("no reply", frame)
                continue
            reply = msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
            tally.replies += 1
            if reply.get("ok"):
                tally.accepted += 1
                before = restore(client, state)
                gen.lease = client.lease
                continue
            code = reply["error"]["code"]
            tally.codes[code] = tally.codes.get(code, 0) + 1
            if code == P.INTERNAL:
                tally.internal += 1
                tally.bad(f"internal ({reply['error']['message']})", frame)
            elif code not in P.ERROR_CODES:
                tally.undocumented += 1
                tally.bad(f"code {code}", frame)
            if tally.frames % 50 == 0 or code == P.INTERNAL:
                after = client.status()
                if status_key(after) != status_key(before) or after["trips"] != before["trips"]:
                    tally.changed_by_rejected += 1
                    tally.bad(f"state {status_key(before)} -> {status_key(after)}", frame)
                    before = restore(client, state)
    finally:
        try:
            client.release_lease()  # for whoever fuzzes next
        except RemoteError:
            pass  # a fuzzed lease.release or a lapse already gave it back
        client.close()
        for sock in socks.values():
            sock.close()
    return tally


def flood(eps: dict[str, str], frames: int, seed: int, state: str = "enabled", drain_s: float = 20.0) -> Tally:
    """``frames`` seeded frames sent as fast as ZeroMQ takes them, from the arm in ``state``,
    each reply read as it comes (a frame beyond ZeroMQ's queues, 1000 a socket, is dropped
    unanswered: docs/protocol.md), then ``drain_s`` for the last replies; the arm put back.
    What the loop pays for the flood is the stats windows' (:func:`overruns`)."""
    client = Client(**eps, timeout=10.0)
    client.acquire_lease(ttl_s=60.0)
    client.keep_lease(1.0)
    socks = _sockets(eps, zmq.Context.instance())
    tally = Tally()

    def take(sock: zmq.Socket) -> None:
        reply = msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
        tally.replies += 1
        if reply.get("ok"):
            tally.accepted += 1
            return
        code = reply["error"]["code"]
        tally.codes[code] = tally.codes.get(code, 0) + 1
        if code == P.INTERNAL:
            tally.internal += 1
            tally.bad(f"internal ({reply['error']['message']})", b"")
        elif code not in P.ERROR_CODES:
            tally.undocumented += 1
            tally.bad(f"code {code}", b"")

    try:
        restore(client, state)
        gen = Frames(seed, client.lease)
        for _ in range(frames):
            frame, control = gen.next()
            socks["control" if control else "command"].send(frame)
            tally.frames += 1
            for sock in socks.values():
                while sock.poll(0):
                    take(sock)
        end = time.monotonic() + drain_s
        while time.monotonic() < end and tally.replies < tally.frames:
            for sock in socks.values():
                while sock.poll(10):
                    take(sock)
        tally.no_reply = tally.frames - tally.replies  # dropped by ZeroMQ at its queue's limit, as documented
        restore(client, state)
    finally:
        try:
            client.release_lease()
        except RemoteError:
            pass
        client.close()
        for sock in socks.values():
            sock.close()
    return tally


@dataclass
class Windows:
    """The loop's stats windows over a stretch of time: overruns, cycles, and its command
    stage (the longest [us], and the largest of the windows' 99.9th percentiles [us])."""
    overruns: int = 0
    cycles: int = 0
    commands_max_us: float = 0.0
    commands_p999_us: float = 0.0

    def __str__(self) -> str:
        return (f"overruns {self.overruns} in {self.cycles} cycles; command stage max {self.commands_max_us:.0f} us, "
                f"worst window's p99.9 {self.commands_p999_us:.0f} us")


def overruns(stats_sub, seconds: float) -> Windows:
    """The stats windows already queued and those of the next ``seconds``."""
    end, out = time.monotonic() + seconds, Windows()
    while stats_sub.poll(max(0, int((end - time.monotonic()) * 1e3))):
        window = msgpack.unpackb(stats_sub.recv_multipart()[1], raw=False)
        out.overruns += window["overruns"]
        out.cycles += window["cycles"]
        commands = window["compute_us"]["commands"]
        out.commands_max_us = max(out.commands_max_us, commands["max"])
        out.commands_p999_us = max(out.commands_p999_us, commands["p99.9"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--idle-half", action="store_true", help="the first half of the frames with the arm idle")
    ap.add_argument("--flood", action="store_true", help="send without waiting for each reply (a flood)")
    ap.add_argument("--no-rt", action="store_true")
    args = ap.parse_args()
    header("protocol fuzz")
    daemon, eps = spawn_daemon(*(["--no-rt"] if args.no_rt else []))
    halves = (("idle", args.frames // 2), ("enabled", args.frames - args.frames // 2)) if args.idle_half else \
        (("enabled", args.frames),)
    try:
        Client(**eps).call("ping", timeout=60.0)
        stats = stats_subscriber(eps)
        time.sleep(1.5)
        overruns(stats, 0.0)  # start-up's windows
        results = []
        for state, frames in halves:
            quiet = overruns(stats, 10.0)  # a quiet window before, the arm as it was
            start = time.monotonic()
            tally = (flood if args.flood else fuzz)(eps, frames, args.seed, state)
            busy = time.monotonic() - start
            results.append((state, tally, busy, quiet, overruns(stats, 0.0)))  # the windows queued while it ran
        alive = daemon.poll() is None
        trips = Client(**eps).status()["trips"]
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    print(f"daemon died: {0 if alive else 1}; trips: {trips}")
    for state, tally, busy, quiet, during in results:
        print(f"-- arm {state}: frames {tally.frames} in {busy:.0f} s, replies {tally.replies}, "
              f"accepted {tally.accepted}")
        print(f"no reply: {tally.no_reply}; internal: {tally.internal}; undocumented codes: {tally.undocumented}; "
              f"state changed by a rejected frame: {tally.changed_by_rejected}")
        print(f"during the fuzz: {during}")
        print(f"10 s before it:  {quiet}")
        print("error codes:", ", ".join(f"{k} {v}" for k, v in sorted(tally.codes.items())))
        for example in tally.examples:
            print("  ", example)


if __name__ == "__main__":
    main()
