"""The messenger: the daemon's ZeroMQ sockets, in a process of their own beside the loop.

It owns the command and control ROUTER sockets and the telemetry PUB socket. Requests go to
the loop, and replies and telemetry come back, through shared-memory rings
(:mod:`daemon.wire.ring`), so the loop passes a message with a memory copy: no system call, no
ZeroMQ call, no serialisation of the state stream (this process turns the loop's binary
rows into msgpack through the cycle record's layout it is given when spawned,
:func:`daemon.wire.telemetry_rows.state_message`), and no Python thread beside the
loop taking the GIL.

Control-socket requests have a ring of their own, which the loop drains first, so an
e-stop never waits behind a flood of commands. The messenger sleeps in one poll on its
sockets and a *doorbell* pipe the loop writes a byte to in a cycle that queued replies (one
cheap system call, only then); telemetry waits at most ``IDLE_POLL_MS`` in its ring.

It also watches the loop: the loop counts its cycles into a shared *heartbeat*; when the
count stops for ``stall_s`` (``STALL_S``) the messenger answers for it instead of leaving clients in
silence (``loop_stalled``: command-socket requests are refused and never reach the loop;
control-socket requests, e-stop first, are still queued for the moment it resumes and said to
be so, and whether the loop's cycle watchdog has written the safe state), and publishes a
``loop_stalled`` event, then ``loop_resumed``; it passes every e-stop on to that watchdog too,
publishes a ``watchdog`` event each time it acted, and answers done (``written_by: watchdog``) the
e-stops its write of the safe state was for (:mod:`daemon.wire.watchdog_link`). Its events share the
``event`` topic's ``seq`` with the loop's (later loop events are renumbered after them). Every
event it publishes is a line of the daemon's log (:mod:`daemon.messenger.journal`), and from
the loop's stats windows it judges the loop's timing against the rig file's ``[timing]``
(:mod:`daemon.messenger.timing`).

It is a helper process (:class:`hal.process.Helper`): it runs at normal priority on the CPUs
the daemon had before its real-time set-up, ends when the loop's telemetry ring says so or
its parent is gone (SIGINT and SIGTERM, which reach the whole process group, are the
daemon's to act on), and the daemon starts another if it dies (:meth:`Messenger.check`):
a spare (:class:`hal.process.Helper`'s, waiting with its imports done) binds the same
endpoints, clients reconnect by themselves and requests in flight are lost (a client's
time-out says so); subscribers see the loss in ``seq``. While no messenger serves, the
lease's clock is held (:mod:`daemon.loop.lease`): its renewals cannot come.

With a key directory (``--keys``), every socket speaks CURVE and admits allowed client keys
only (:mod:`daemon.messenger.guard`); each request goes to the loop with who sent it
(:mod:`daemon.wire.routed`), and SIGHUP or a ``keys.reload`` request (answered here,
never by the loop) reads the allow-list again.
"""
from __future__ import annotations

import logging
import os
import signal
import time

import zmq

from daemon.messenger.guard import Guard
from daemon.messenger.shared import (
    CLOSE_LINGER_MS,
    END,
    STALL_S,
    TOPICS,
    Heartbeat,
    open_socket,
    reloads,
)
from daemon.wire.keys import KeyFileError
from daemon.wire.ring import Ring
from daemon.wire.watchdog_link import WatchdogLink
from hal.rig_sections import FlightRecorderConfig, TimingConfig
from hal.process import Child, Helper, HelperFailed

__all__ = ["END", "STALL_S", "TOPICS", "Heartbeat", "Messenger", "MessengerError", "create_rings"]  # the loop's side
RING_BYTES = {"telemetry": 1 << 20, "control": 1 << 20, "command": 1 << 20, "replies": 1 << 20}
ANNOUNCE_S = 1.0  # a restart's event this long after the new messenger is ready: its subscribers are back [s]
log = logging.getLogger("pneumad")


class MessengerError(RuntimeError):
    """The messenger could not start (its own words: e.g. an endpoint is in use)."""


def create_rings(directory: str) -> dict[str, Ring]:
    return {name: Ring(os.path.join(directory, name), size) for name, size in RING_BYTES.items()}


class Messenger:
    """The daemon's handle on the messenger process."""

    def __init__(self, rings_dir: str, doorbell: int, command: str, control: str, telemetry: str,
                 stall_s: float = STALL_S, keys: str | None = None, recorder: bool = False,
                 plotjuggler: str | None = None, foxglove: tuple[str, int] | None = None,
                 timing: TimingConfig | None = None, layout: list[dict] | None = None,
                 flight: FlightRecorderConfig | None = None, model: bool = False):
        self.rings_dir = rings_dir
        self.model = model  # hand the state messages to the model process and publish what it says
        self.layout = layout  # the cycle record's fields (CycleLayout.describe): how a state batch reads
        self.flight = flight  # the rig file's [flight_recorder] (with a recorder): trips name their flight files
        self.timing = timing  # the rig file's [timing]: the messenger judges the loop's timing by it
        self.foxglove = foxglove  # (host, port) of the live Foxglove stream (daemon.messenger.foxglove_stream)
        self.plotjuggler = plotjuggler  # an endpoint for PlotJuggler's rows (daemon.messenger.plotjuggler)
        self.recorder = recorder  # hand telemetry and record.* requests to the recorder process
        self.stall_s = stall_s
        self.keys = keys
        self.doorbell = doorbell  # the read end of the loop's doorbell pipe, handed on to the process
        self.asked = {"command": command, "control": control, "telemetry": telemetry}
        self.endpoints: dict[str, str] = {}  # as bound (wildcard ports resolved)
        self._cpus = os.sched_getaffinity(0)  # before the daemon's real-time set-up
        self._proc: Helper | None = None
        self.down = False  # from a death seen until its successor is ready: no requests, no renewals come
        self._down_since = 0.0  # [s] monotonic, when the death was seen
        self._announce: tuple[float, str] | None = None  # (when [s], what): the restart's event, once due

    @property
    def restarts(self) -> int:
        return self._proc.restarts if self._proc is not None else 0

    def start(self) -> dict[str, str]:
        """Start the process and wait until it has bound its sockets; the endpoints."""
        self._proc = self._helper(self.asked)
        try:
            self.endpoints = self._proc.start()
        except HelperFailed as exc:
            raise MessengerError(str(exc)) from None
        self._proc.args = self._args(self.endpoints)  # a restarted one (and the spare) binds the same ports again
        return self.endpoints

    def _helper(self, endpoints: dict[str, str]) -> Helper:
        return Helper("daemon.messenger.process:serve", self._args(endpoints), name="the messenger process",
                      pass_fds=(self.doorbell,), nice=0, cpus=self._cpus, spare=True)

    def _args(self, endpoints: dict[str, str]) -> tuple:
        return (self.rings_dir, self.doorbell, self.stall_s, self.keys, self.recorder, self.plotjuggler, endpoints,
                self.foxglove, self.timing, self.layout, self.flight, self.model)

    def check(self) -> str | None:
        """Called from the loop (every ``daemon.loop.port.MESSENGER_CHECK_CYCLES``), never
        blocking: if the process has died, put its spare in service (or start another) on the
        same endpoints without waiting for it; :attr:`down` until it is ready. ``ANNOUNCE_S``
        after that (time for subscribers to reconnect), say what happened: an ``event``'s
        cause, which the messenger logs as it publishes it."""
        now = time.monotonic()
        code = self._proc.restart_if_dead()
        if code is not None:
            if not self.down:
                self.down, self._down_since = True, now
            return None
        if self.down:
            try:
                ready = self._proc.poll_ready()
            except HelperFailed as exc:  # it refused (its endpoint taken meanwhile): the next check starts another
                log.error("the restarted messenger process did not start: %s", exc)
                return None
            if ready:
                self.down = False
                self._announce = (now + ANNOUNCE_S, f"the messenger process exited (code {self._proc.last_exit_code}) "
                                                    f"and was restarted (restart {self.restarts}); no messenger for "
                                                    f"{now - self._down_since:.2f} s after its death was seen")
        if self._announce is not None and now >= self._announce[0]:
            cause, self._announce = self._announce[1], None
            return cause
        return None

    def health(self) -> dict:
        """The process as of the last check (daemon.loop.port's status field ``helpers``)."""
        return self._proc.health() if self._proc is not None else {}

    def reload_keys(self) -> None:
        """Ask the process to read its allow-list again (SIGHUP: no waiting)."""
        if self._proc is not None:
            self._proc.send_signal(signal.SIGHUP)

    def join(self, timeout: float = 2.0) -> None:
        """Wait for the process to end once the telemetry ring's END is queued; kill it if not."""
        if self._proc is not None:
            self._proc.join(timeout)


# -- in the messenger process ---------------------------------------------------------------
def serve(child: Child, rings_dir: str, doorbell: int, stall_s: float, keys: str | None, recorder: bool,
          plotjuggler: str | None, endpoints: dict[str, str], foxglove: tuple[str, int] | None = None,
          timing: TimingConfig | None = None, layout: list[dict] | None = None,
          flight: FlightRecorderConfig | None = None, model: bool = False) -> int:
    """The messenger process's main: its imports (where a spare waits: Child.standby), then
    bind the sockets, say ready with their endpoints, relay until the loop's END or the
    parent's end."""
    logging.basicConfig(level=logging.INFO, format="pneumad messenger %(levelname)s: %(message)s")
    from daemon.messenger.recorder_link import (
        Recorder,  # the process's own work: the daemon's side never needs them
    )
    from daemon.messenger.model_link import ModelLink
    from daemon.messenger.relay import Relay
    from daemon.wire.cycle_layout import CycleLayout
    from daemon.wire.loop_stats import StatsBanks
    if plotjuggler:
        from daemon.messenger.plotjuggler import PlotJugglerFeed
    if foxglove:
        from daemon.messenger.foxglove_stream import FoxgloveStream
    child.standby()
    cycle_layout = CycleLayout.from_describe(layout)
    ctx = zmq.Context()
    try:
        guard = Guard(ctx, keys) if keys else None
    except KeyFileError as exc:
        raise HelperFailed(f"cannot use the keys: {exc}") from None
    signal.signal(signal.SIGHUP, lambda *_: reloads.append(1))  # systemctl reload, or the daemon's SIGHUP
    sockets = {}
    feed = None
    link = None
    model_link = None
    try:
        for name in ("command", "control", "telemetry"):
            sockets[name] = open_socket(ctx, name, endpoints[name], guard)
        if plotjuggler:
            name = "plotjuggler"
            feed = PlotJugglerFeed(ctx, plotjuggler, rings_dir, cycle_layout)
        if recorder:
            name = "recorder"
            link = Recorder(ctx, rings_dir)
        if model:
            name = "model"
            model_link = ModelLink(ctx, rings_dir)
    except zmq.ZMQError as exc:
        where = {"plotjuggler": plotjuggler, "recorder": "(its feed)", "model": "(its feed)"}.get(name) or endpoints[name]
        raise HelperFailed(f"cannot bind the {name} endpoint {where}: {exc}") from None
    stream = None
    if foxglove:
        try:
            stream = FoxgloveStream(*foxglove, rings_dir)
        except RuntimeError as exc:
            raise HelperFailed(f"cannot serve Foxglove on {foxglove[0]}:{foxglove[1]}: {exc}") from None
    rings = {name: Ring(os.path.join(rings_dir, name)) for name in RING_BYTES}
    stats = StatsBanks.in_directory(rings_dir, create=False)
    stats.reclaim()
    child.ready({n: sockets[n].getsockopt_string(zmq.LAST_ENDPOINT) for n in ("command", "control", "telemetry")})
    watchdog = WatchdogLink(rings_dir)
    Relay(sockets, rings, doorbell, Heartbeat(rings_dir), stats, cycle_layout, stall_s, guard,
          link, feed, stream, timing=timing, flight=flight, model=model_link, watchdog=watchdog).run(child.parent_alive)
    watchdog.close()
    for helper in (link, feed, stream, model_link):
        if helper is not None:
            helper.close()
    sockets["telemetry"].setsockopt(zmq.LINGER, CLOSE_LINGER_MS)
    for sock in sockets.values():
        sock.close()
    if guard is not None:
        guard.close()
    ctx.term()
    return 0
