"""The real loop in this process on a virtual clock with the simulated rig, served on private
ports, and ZeroMQ peers that drive it a cycle at a time until their reply comes."""
from __future__ import annotations

import math
import time
from contextlib import contextmanager
from typing import Iterator

import msgpack
import zmq

from daemon import assembly
from daemon.loop.clock import VirtualClock
from daemon.loop.cycle import ControlLoop
from daemon.loop.port import ZmqServer
from daemon.planner.process import Preparer
from daemon.wire import protocol
from daemon.wire.loop_stats import StatsBanks, summarise
from daemon.wire.telemetry_rows import state_message, to_payload
from hal import config

PRIVATE = "tcp://127.0.0.1:*"  # a free port per socket, never the default endpoints


class Captured:
    """A telemetry sink that keeps every message as subscribers would see it, decoded. Kept
    as sent and decoded when first read: a test reads a part of what a long run sends, and
    decoding every batch as it came cost a tenth of each cycle."""

    def __init__(self):
        self._messages: list[tuple[str, dict | bytes]] = []  # bytes: a body not yet decoded
        self._decoded = 0  # the messages before this index are decoded
        self.stats: StatsBanks | None = None  # the loop's histograms (LoopStats.banks), to summarise its windows
        self.release_stats = True  # False beside a messenger, which clears and hands the banks back itself
        self.layout = None  # the loop's cycle layout (follow): how its state batches read

    def __call__(self, topic: bytes, body: bytes | bytearray | memoryview) -> None:
        if topic == b"stats":  # summarised now: the banks it reads move on
            self._messages.append(("stats", summarise(self.stats, body, self.release_stats)))
        else:
            self._messages.append((topic.decode(), bytes(body)))  # a view of a buffer the loop reuses

    @property
    def messages(self) -> list[tuple[str, dict]]:
        for i in range(self._decoded, len(self._messages)):
            topic, body = self._messages[i]
            if isinstance(body, bytes):  # a state batch's columns are already what a subscriber decodes
                self._messages[i] = (topic, state_message(self.layout, body) if topic == "state" else
                                     msgpack.unpackb(to_payload(self.layout, topic.encode(), body), raw=False))
        self._decoded = len(self._messages)
        return self._messages

    def follow(self, loop: ControlLoop, beside_messenger: bool = False) -> None:
        """Read ``loop``'s state batches on its layout and summarise its stats windows, as its
        messenger would."""
        self.stats, self.release_stats = loop.stats.banks, not beside_messenger
        self.layout = loop.layout

    def of(self, topic: str) -> list[dict]:
        return [m for t, m in self.messages if t == topic]

    def drain(self, topic: str) -> list[dict]:
        """The messages of ``topic`` so far, every message kept so far forgotten (a long run read
        a part at a time)."""
        found = self.of(topic)
        self._messages, self._decoded = [], 0
        return found

    def fields(self, group: str, quantity: str | None = None) -> list[str]:
        """The names of the layout's fields of ``group`` (one ``quantity`` of it), in record
        order: ``fields("measured", "position")`` is each joint's position, in joint order."""
        return [f.name for f in self.layout.of_group(group) if quantity is None or f.quantity == quantity]

    def series(self, names: list[str]):
        """(cycle, [the named fields' values]) for each cycle of the state stream."""
        for m in self.of("state"):
            columns = [m[name] for name in names]
            for k, cycle in enumerate(m["cycle"]):
                yield cycle, [column[k] for column in columns]


def virtual_loop(rig: config.RigConfig, controller: str = "pid", publish=None,
                 plugins: dict[str, str] | None = None, stats_banks=None) -> ControlLoop:
    """The loop on ``rig`` on a fresh virtual clock (not started): it cycles only when run,
    as fast as the machine goes. No contact-sensor process: its frames come in real time."""
    return assembly.build_loop(rig, VirtualClock(), 0.001, controller, plugins, publish, contact=False,
                               stats_banks=stats_banks)


def make_loop(rig_text: str | None = None, server: bool = False, controller: str = "pid", loop_stall_s: float = 60.0,
              plugins: dict[str, str] | None = None,
              preparer: Preparer | None = None) -> tuple[ControlLoop, Captured, ZmqServer | None]:
    """The loop on a virtual clock, started, its telemetry captured, and (``server``) served
    on private ports with ``preparer`` (default: the session's planner worker, spawned with the
    ``sys.path`` of the first test that asked: a plugin a test put on its path needs a worker
    of its own). It cycles only while a test runs it, so the messenger's stall watch
    (``loop_stall_s``) is set long: a test that thinks for a second between two requests has
    not stalled a real-time loop."""
    rig = config.parse(rig_text) if rig_text else config.load()
    srv = ZmqServer(PRIVATE, PRIVATE, PRIVATE, loop_stall_s=loop_stall_s,
                    layout=assembly.cycle_layout(rig)) if server else None
    captured = Captured()
    send = captured if srv is None else (lambda topic, payload: (captured(topic, payload), srv.publish(topic, payload)))
    loop = virtual_loop(rig, controller, send, plugins, srv.stats_banks if srv is not None else None)
    if srv is not None:
        if preparer is None:
            preparer = shared_preparer()
            while preparer.check() is not None:  # an earlier test's replaced worker: not this loop's event
                pass
        srv.attach(loop, preparer)
    captured.follow(loop, beside_messenger=srv is not None)
    loop.start()
    return loop, captured, srv


@contextmanager
def served_loop() -> Iterator[tuple[ControlLoop, Captured, ZmqServer]]:
    """A served :func:`make_loop` run 100 cycles: (loop, captured, server), the server closed after."""
    loop, captured, srv = make_loop(server=True)
    loop.run(100)
    try:
        yield loop, captured, srv
    finally:
        srv.close()


_preparer: list[Preparer] = []


def shared_preparer() -> Preparer:
    """One planner worker for every in-process loop of a session, spawned and warmed once
    (a worker per test cost 1.5 s of start-up each). A job's reply always comes before its
    test ends, so no test inherits another's work."""
    if not _preparer:
        # 120 s, not the daemon's 30 s: a worker spawned on a machine busy with other test
        # processes has taken over 30 s to import the controllers (a test that needs a hang
        # noticed sooner sets its own limit)
        _preparer.append(Preparer(time_limit_s=120.0))
        _preparer[0].warm().result(timeout=120)
    return _preparer[0]


def dealer(srv: ZmqServer, which: str = "command") -> zmq.Socket:
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(srv.endpoints[which])
    return sock


def exchange(loop: ControlLoop, sock: zmq.Socket, payload: bytes, limit_s: float = 120.0, each_cycle=None):
    """Send raw bytes and run the loop until the reply arrives; the decoded reply (or None
    after ``limit_s`` of wall time: the reply is waited for, however busy the machine, e.g. a
    build in the niced planner beside two CPU hogs; 5000 cycles were too few there).
    ``each_cycle``, if given, is called after every cycle the exchange runs.

    The virtual clock moves only by the cycles the request needs, not by how fast this
    machine's processes pass it on: the loop runs its first cycle once the messenger has queued
    the request for it (or answered it itself: a cycle still runs), and then one cycle per
    millisecond of real time at most while the reply is on its way (a loaded machine once let
    0.1 s of virtual time pass between two requests a test sent 0.5 s apart)."""
    sock.send(payload)
    deadline = time.monotonic() + limit_s
    rings = tuple(loop.server.rings[name] for name in ("command", "control")) if loop.server is not None else ()
    while rings and not any(ring.pending() for ring in rings) and not sock.poll(1) and time.monotonic() < deadline:
        pass
    while time.monotonic() < deadline:
        loop.run(1)
        if each_cycle is not None:
            each_cycle()
        if sock.poll(1):
            return msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
    return None


_ids = iter(range(1, 10**9))


def call(loop, sock, cmd, args=None, lease=None):
    reply = exchange(loop, sock, protocol.encode_request(next(_ids), cmd, args, lease))
    assert reply is not None, f"no reply to {cmd}"
    return reply


def ok(loop, sock, cmd, args=None, lease=None):
    reply = call(loop, sock, cmd, args, lease)
    assert reply["ok"], reply
    return reply["result"]


def leased(loop: ControlLoop, sock: zmq.Socket) -> str:
    """The lease for 60 s, not the rig's 2 s: a deferred command's reply is waited for while the
    loop cycles about in real time, and beside CPU hogs the planner (then at nice 19) took over 2 s to
    derive a controller's parameters (the lease expired between two requests: no_lease)."""
    return ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]


def run_seconds(loop: ControlLoop, seconds: float) -> None:
    loop.run(int(round(seconds / loop.period)))


def tracking(captured: Captured, after_cycle: int = 0) -> tuple[list[float], list[float]]:
    """Max |error| per joint [deg] and RMS per joint [deg] over the state stream."""
    errors = [e for c, e in captured.series(captured.fields("reference", "error")) if c > after_cycle]
    n = len(errors[0])
    worst = [max(abs(math.degrees(e[j])) for e in errors) for j in range(n)]
    rms = [math.sqrt(sum(math.degrees(e[j]) ** 2 for e in errors) / len(errors)) for j in range(n)]
    return worst, rms
