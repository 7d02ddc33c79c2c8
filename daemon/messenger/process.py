"""The messenger: the daemon's ZeroMQ sockets, in a process of their own beside the loop.

It owns the command and control ROUTER sockets and the telemetry PUB socket. Requests go to
the loop, and replies and telemetry come back, through shared-memory rings
(:mod:`daemon.wire.ring`), so the loop passes a message with a memory copy: no system call, no
ZeroMQ call, no serialisation of the state stream (this process turns the loop's binary
rows into msgpack, :func:`daemon.loop.telemetry.to_payload`), and no Python thread beside the
loop taking the GIL.

Control-socket requests have a ring of their own, which the loop drains first, so an
e-stop never waits behind a flood of commands. The messenger sleeps in one poll on its
sockets and a *doorbell* pipe the loop writes a byte to in a cycle that queued replies (one
cheap system call, only then); telemetry waits at most ``IDLE_POLL_MS`` in its ring.

It also watches the loop: the loop counts its cycles into a shared *heartbeat*; when the
count stops for ``stall_s`` (``STALL_S``) the messenger answers for it instead of leaving clients in
silence (``loop_stalled``: command-socket requests are refused and never reach the loop;
control-socket requests, e-stop first, are still queued for the moment it resumes and said to
be so), and publishes a ``loop_stalled`` event, then ``loop_resumed``. Its events share the
``event`` topic's ``seq`` with the loop's (later loop events are renumbered after them).

It runs at normal priority on the CPUs the daemon had before its real-time set-up, ends
when the loop's telemetry ring says so or its parent is gone (SIGINT and SIGTERM, which
reach the whole process group, are the daemon's to act on), and the daemon starts another
if it dies (:meth:`Messenger.check`): clients reconnect by themselves and requests in flight
are lost (a client's time-out says so); subscribers see the loss in ``seq``.

With a key directory (``--keys``), every socket speaks CURVE and admits allowed client keys
only (:mod:`daemon.messenger.guard`); each request goes to the loop with who sent it
(:func:`daemon.wire.keys.pack_identity`), and SIGHUP or a ``keys.reload`` request (answered here,
never by the loop) reads the allow-list again.

    python -c 'from daemon.messenger.process import main; main()' --rings DIR --doorbell FD --command EP --control EP --telemetry EP [--cpus 0,1]
                               [--stall-s 0.5] [--keys DIR] [--recorder] [--plotjuggler EP]
"""
from __future__ import annotations

import argparse
import logging
import mmap
import os
import select
import signal
import struct
import subprocess
import sys

import zmq

from daemon.wire import protocol

from daemon.service import realtime
from daemon.messenger.guard import Guard
from daemon.wire.keys import KeyFileError
from daemon.wire.ring import Ring
from hal.offloop import die_with_parent

TOPICS = (b"", b"state", b"stats", b"event", b"internals", b"contact")  # telemetry ring tags; 0 ends the stream
END = 0
RING_BYTES = {"telemetry": 1 << 20, "control": 1 << 20, "command": 1 << 20, "replies": 1 << 20}
TELEMETRY_HWM = 1000  # messages queued per subscriber before ZeroMQ drops (100 ms of state batches)
ROUTER_HWM = 1000
IDLE_POLL_MS = 2  # telemetry waits at most this long in the ring [ms]
OWED_LIMIT_S = 60.0  # a reply owed this long is forgotten (the loop always answers sooner)
CLOSE_LINGER_MS = 500  # how long the last messages may take to leave at exit
STALL_S = 0.5  # a loop whose cycle count has not moved for this long is answered for [s] (default)
_BEAT = struct.Struct("<Q")
START_TIMEOUT_S = 30.0
log = logging.getLogger("pneumad")


class MessengerError(RuntimeError):
    """The messenger could not start (its own words: e.g. an endpoint is in use)."""


def create_rings(directory: str) -> dict[str, Ring]:
    return {name: Ring(os.path.join(directory, name), size) for name, size in RING_BYTES.items()}


class Heartbeat:
    """The loop's cycle count in shared memory: the loop writes it every cycle (one store),
    the messenger reads it to tell a running loop from a stalled one."""

    def __init__(self, directory: str, create: bool = False):
        path = os.path.join(directory, "heartbeat")
        if create:
            with open(path, "wb") as f:
                f.truncate(_BEAT.size)
        fd = os.open(path, os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, _BEAT.size)
        finally:
            os.close(fd)

    def beat(self, cycle: int) -> None:
        _BEAT.pack_into(self._map, 0, cycle)

    def read(self) -> int:
        return _BEAT.unpack_from(self._map, 0)[0]

    def close(self) -> None:
        self._map.close()


class Messenger:
    """The daemon's handle on the messenger process."""

    def __init__(self, rings_dir: str, doorbell: int, command: str, control: str, telemetry: str,
                 stall_s: float = STALL_S, keys: str | None = None, recorder: bool = False,
                 plotjuggler: str | None = None):
        self.rings_dir = rings_dir
        self.plotjuggler = plotjuggler  # an endpoint for PlotJuggler's rows (daemon.messenger.plotjuggler)
        self.recorder = recorder  # hand telemetry and record.* requests to the recorder process
        self.stall_s = stall_s
        self.keys = keys
        self.doorbell = doorbell  # the read end of the loop's doorbell pipe, handed on to the process
        self.asked = {"command": command, "control": control, "telemetry": telemetry}
        self.endpoints: dict[str, str] = {}  # as bound (wildcard ports resolved)
        self.restarts = 0
        self._cpus = ",".join(map(str, sorted(os.sched_getaffinity(0))))
        self._proc: subprocess.Popen | None = None
        self._restart = ""  # a restart under way: "starting", then "ready"

    def start(self) -> dict[str, str]:
        """Start the process and wait until it has bound its sockets; the endpoints."""
        self._spawn(self.asked)
        line = self._line(START_TIMEOUT_S)
        if not line.startswith("ready "):
            self._proc.kill()
            self._proc.wait()
            raise MessengerError(line or "the messenger process did not start")
        self.endpoints = dict(zip(("command", "control", "telemetry"), line.split()[1:]))
        return self.endpoints

    def _spawn(self, endpoints: dict[str, str]) -> None:
        self._proc = subprocess.Popen(
            # Imported, not run as __main__: daemon.messenger.relay shares this module's state (the reloads).
            [sys.executable, "-c", "import sys; from daemon.messenger.process import main; sys.exit(main())", "--rings", self.rings_dir, "--doorbell", str(self.doorbell),
             "--cpus", self._cpus, "--stall-s", str(self.stall_s), *(["--keys", self.keys] if self.keys else []),
             *(["--recorder"] if self.recorder else []), *(["--plotjuggler", self.plotjuggler] if self.plotjuggler else []),
             *sum(([f"--{k}", v] for k, v in endpoints.items()), [])],
            stdout=subprocess.PIPE, text=True, pass_fds=(self.doorbell,))

    def _line(self, timeout: float) -> str:
        """The process's next line on stdout within ``timeout`` [s] ('' if none)."""
        if select.select([self._proc.stdout], [], [], timeout)[0]:
            return self._proc.stdout.readline().strip()
        return ""

    def check(self) -> str | None:
        """Called once a second from the loop, never blocking: if the process has died, start
        another on the same endpoints without waiting for it, and log it (the 1st, 2nd, 4th ...
        restart). One check after the new one is ready (time for subscribers to reconnect),
        say what happened: an ``event``'s cause."""
        code = self._proc.poll()
        if code is not None:
            self.restarts += 1
            if self.restarts & (self.restarts - 1) == 0:  # the 1st, 2nd, 4th, 8th ...: a stuck one does not flood the log
                log.error("the messenger process exited (code %s); starting another (restart %d)", code, self.restarts)
            self._proc.stdout.close()
            self._spawn(self.endpoints)
            self._restart = "starting"
        elif self._restart == "ready":
            self._restart = ""
            return f"the messenger process stopped and was restarted (restart {self.restarts})"
        elif self._restart == "starting" and self._line(0.0).startswith("ready "):
            self._restart = "ready"
        return None

    def reload_keys(self) -> None:
        """Ask the process to read its allow-list again (SIGHUP: no waiting)."""
        if self._proc is not None and self._proc.poll() is None:
            self._proc.send_signal(signal.SIGHUP)

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def join(self, timeout: float = 2.0) -> None:
        """Wait for the process to end once the telemetry ring's END is queued; kill it if not."""
        if self._proc is None:
            return
        try:
            self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._proc.stdout.close()
        self._proc = None


# -- in the messenger process ---------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="pneumad-messenger", description=__doc__)
    ap.add_argument("--rings", required=True)
    ap.add_argument("--doorbell", type=int, required=True)
    for name in ("command", "control", "telemetry"):
        ap.add_argument(f"--{name}", required=True)
    ap.add_argument("--cpus", default="")
    ap.add_argument("--stall-s", type=float, default=STALL_S)
    ap.add_argument("--keys", default=None)
    ap.add_argument("--recorder", action="store_true", help="the daemon runs a recorder process (daemon.recorder.process)")
    ap.add_argument("--plotjuggler", default=None, help="an endpoint for PlotJuggler's rows (daemon.messenger.plotjuggler)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="pneumad messenger %(levelname)s: %(message)s")
    parent = os.getppid()
    die_with_parent()
    # Ctrl-C and systemctl stop reach the whole process group; the daemon decides when this
    # ends (END, after its last events), or its death does.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    realtime.leave_real_time([int(c) for c in args.cpus.split(",") if c])
    ctx = zmq.Context()
    try:
        guard = Guard(ctx, args.keys) if args.keys else None
    except KeyFileError as exc:
        print(f"cannot use the keys: {exc}", flush=True)
        return 1
    signal.signal(signal.SIGHUP, lambda *_: reloads.append(1))  # systemctl reload, or the daemon's SIGHUP
    sockets = {}
    plotjuggler = None
    try:
        for name in ("command", "control", "telemetry"):
            sockets[name] = open_socket(ctx, name, getattr(args, name), guard)
        if args.plotjuggler:
            from daemon.messenger.plotjuggler import PlotJugglerFeed
            name = "plotjuggler"
            plotjuggler = PlotJugglerFeed(ctx, args.plotjuggler, args.rings)
    except zmq.ZMQError as exc:
        print(f"cannot bind the {name} endpoint {getattr(args, name)}: {exc}", flush=True)
        return 1
    from daemon.messenger.recorder_link import (
        Recorder,  # the process's own work: the daemon's side never needs them
    )
    from daemon.messenger.relay import Relay
    from daemon.wire.loop_stats import StatsBanks
    rings = {name: Ring(os.path.join(args.rings, name)) for name in RING_BYTES}
    recorder = Recorder(ctx, args.rings) if args.recorder else None
    print("ready", *(sockets[n].getsockopt_string(zmq.LAST_ENDPOINT) for n in ("command", "control", "telemetry")),
          flush=True)
    stats = StatsBanks.in_directory(args.rings, create=False)
    stats.reclaim()
    Relay(sockets, rings, args.doorbell, Heartbeat(args.rings), stats, args.stall_s, guard, recorder,
          plotjuggler).run(lambda: os.getppid() == parent)
    for helper in (recorder, plotjuggler):
        if helper is not None:
            helper.close()
    sockets["telemetry"].setsockopt(zmq.LINGER, CLOSE_LINGER_MS)
    for sock in sockets.values():
        sock.close()
    if guard is not None:
        guard.close()
    ctx.term()
    return 0


reloads: list[int] = []  # SIGHUPs not yet acted on


def open_socket(ctx: zmq.Context, name: str, endpoint: str, guard: Guard | None) -> zmq.Socket:
    """One of the daemon's sockets, bound (ZMQError if it cannot be)."""
    sock = ctx.socket(zmq.PUB if name == "telemetry" else zmq.ROUTER)
    sock.setsockopt(zmq.LINGER, 0)
    if name == "telemetry":
        sock.setsockopt(zmq.SNDHWM, TELEMETRY_HWM)
    else:
        sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_MESSAGE_BYTES)
        sock.setsockopt(zmq.RCVHWM, ROUTER_HWM)
        sock.setsockopt(zmq.SNDHWM, ROUTER_HWM)
    if guard is not None:
        guard.secure(sock)
    try:
        sock.bind(endpoint)
    except zmq.ZMQError:
        sock.close()
        raise
    return sock
