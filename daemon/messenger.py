"""The messenger: the daemon's ZeroMQ sockets, in a process of their own beside the loop.

It owns the command and control ROUTER sockets and the telemetry PUB socket. Requests go to
the loop, and replies and telemetry come back, through shared-memory rings
(:mod:`daemon.ring`), so the loop passes a message with a memory copy: no system call, no
ZeroMQ call, no serialisation of the state stream (this process turns the loop's binary
rows into msgpack, :func:`daemon.telemetry.to_payload`), and no Python thread beside the
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

    python -m daemon.messenger --rings DIR --doorbell FD --command EP --control EP --telemetry EP [--cpus 0,1]
                               [--stall-s 0.5]
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
import time

import msgpack
import zmq

from daemon import protocol, realtime
from daemon.ring import Ring, RingError
from daemon.telemetry import to_payload
from hal.offloop import die_with_parent

TOPICS = (b"", b"state", b"stats", b"event")  # telemetry ring tags; 0 ends the stream
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
                 stall_s: float = STALL_S):
        self.rings_dir = rings_dir
        self.stall_s = stall_s
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
            [sys.executable, "-m", "daemon.messenger", "--rings", self.rings_dir, "--doorbell", str(self.doorbell),
             "--cpus", self._cpus, "--stall-s", str(self.stall_s), *sum(([f"--{k}", v] for k, v in endpoints.items()), [])],
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
    args = ap.parse_args(argv)
    parent = os.getppid()
    die_with_parent()
    # Ctrl-C and systemctl stop reach the whole process group; the daemon decides when this
    # ends (END, after its last events), or its death does.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    realtime.leave_real_time([int(c) for c in args.cpus.split(",") if c])
    ctx = zmq.Context()
    sockets = {}
    for name, kind in (("command", zmq.ROUTER), ("control", zmq.ROUTER), ("telemetry", zmq.PUB)):
        sock = sockets[name] = ctx.socket(kind)
        sock.setsockopt(zmq.LINGER, 0)
        if kind == zmq.ROUTER:
            sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_MESSAGE_BYTES)
            sock.setsockopt(zmq.RCVHWM, ROUTER_HWM)
            sock.setsockopt(zmq.SNDHWM, ROUTER_HWM)
        else:
            sock.setsockopt(zmq.SNDHWM, TELEMETRY_HWM)
        endpoint = getattr(args, name)
        try:
            sock.bind(endpoint)
        except zmq.ZMQError as exc:
            print(f"cannot bind the {name} endpoint {endpoint}: {exc}", flush=True)
            return 1
    rings = {name: Ring(os.path.join(args.rings, name)) for name in RING_BYTES}
    print("ready", *(sockets[n].getsockopt_string(zmq.LAST_ENDPOINT) for n in ("command", "control", "telemetry")),
          flush=True)
    Relay(sockets, rings, args.doorbell, Heartbeat(args.rings), args.stall_s).run(lambda: os.getppid() == parent)
    sockets["telemetry"].setsockopt(zmq.LINGER, CLOSE_LINGER_MS)
    for sock in sockets.values():
        sock.close()
    ctx.term()
    return 0


class Relay:
    """Moves requests from the ROUTER sockets into the loop's rings, and replies and
    telemetry from the loop's rings onto the sockets."""

    def __init__(self, sockets: dict[str, zmq.Socket], rings: dict[str, Ring], doorbell: int, heartbeat: Heartbeat,
                 stall_s: float = STALL_S):
        self.sockets, self.rings, self.doorbell, self.heartbeat = sockets, rings, doorbell, heartbeat
        self.stall_s = stall_s
        self.owed: dict[int, tuple[zmq.Socket, list, float, object]] = {}  # token -> (socket, envelope, when, id)
        self._cycle, self._cycle_seen = heartbeat.read(), time.monotonic()  # the loop's count and when it moved
        self.stalled_since: float | None = None
        self._event_seq = 0  # the last event seq sent
        self._injected = 0  # events of this process's own so far: loop events are renumbered after them
        self._tokens = iter(range(1, 1 << 62))
        self.poller = zmq.Poller()
        for name in ("control", "command"):
            self.poller.register(sockets[name], zmq.POLLIN)
        self.poller.register(doorbell, zmq.POLLIN)

    def run(self, parent_alive) -> None:
        """Until the telemetry ring's END, or until the parent is gone."""
        last_check = time.monotonic()
        while True:
            ready = dict(self.poller.poll(IDLE_POLL_MS))
            for name in ("control", "command"):  # control first: an e-stop overtakes a flood
                if self.sockets[name] in ready:
                    self._take_requests(name)
            if self.doorbell in ready:
                os.read(self.doorbell, 4096)  # the rings say what there is; the bytes only woke us
            self._send_replies()
            if not self._publish():
                self._send_replies()  # the loop's last answers, then stop
                return
            now = time.monotonic()
            self._watch_loop(now)
            if now - last_check > 0.5:
                last_check = now
                if not parent_alive():
                    return
                self.owed = {t: o for t, o in self.owed.items() if now - o[2] < OWED_LIMIT_S}

    def _take_requests(self, name: str) -> None:
        """Every waiting request that fits in the loop's ring; the rest stay queued in ZeroMQ.
        While the loop is stalled, command-socket requests are refused here instead."""
        sock, ring = self.sockets[name], self.rings[name]
        while ring.free() >= protocol.MAX_MESSAGE_BYTES + 64:
            try:
                frames = sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if self.stalled_since is not None and name == "command":
                self._answer_stalled(sock, frames[:-1], _request_id(frames[-1]),
                                     "refused without reaching the loop: nothing was done")
                continue
            token = next(self._tokens)
            ring.put(token, frames[-1])
            if self.stalled_since is not None:  # a control request: kept for the loop, answered now
                self._answer_stalled(sock, frames[:-1], _request_id(frames[-1]),
                                     "queued: it takes effect if the loop resumes")
            else:
                self.owed[token] = (sock, frames[:-1], time.monotonic(), _request_id(frames[-1]))

    # -- the loop's heartbeat --------------------------------------------------------------
    def _watch_loop(self, now: float) -> None:
        cycle = self.heartbeat.read()
        if cycle != self._cycle:
            self._cycle, self._cycle_seen = cycle, now
            if self.stalled_since is not None:
                self._event({"kind": "loop_resumed", "cycle": cycle, "stalled_s": now - self.stalled_since})
                self.stalled_since = None
        elif cycle and self.stalled_since is None and now - self._cycle_seen > self.stall_s:
            self.stalled_since = self._cycle_seen
            self._event({"kind": "loop_stalled", "cycle": cycle,
                         "cause": f"the loop has not cycled for {(now - self._cycle_seen) * 1e3:.0f} ms"})
            for token, (sock, envelope, _, request_id) in list(self.owed.items()):  # taken before the stall
                del self.owed[token]
                self._answer_stalled(sock, envelope, request_id, "taken before the stall: it runs if the loop resumes, "
                                                           "and its own reply is lost")

    def _answer_stalled(self, sock: zmq.Socket, envelope: list, request_id, what: str) -> None:
        since = time.monotonic() - self._cycle_seen
        reply = protocol.encode_error(request_id, protocol.LOOP_STALLED,
                                      f"the control loop has not cycled for {since:.1f} s (last cycle {self._cycle}); "
                                      f"this request was {what}",
                                      {"reason": "loop_stalled", "stalled_s": since, "cycle": self._cycle})
        try:
            sock.send_multipart([*envelope, reply], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass

    def _event(self, event: dict) -> None:
        """Publish an event of the messenger's own, numbered in the loop's event sequence."""
        self._injected += 1
        self._event_seq += 1
        body = msgpack.packb({"t": time.monotonic(), **event, "seq": self._event_seq, "source": "messenger"})
        self.sockets["telemetry"].send_multipart((b"event", body))

    def _send_replies(self) -> None:
        ring = self.rings["replies"]
        while (entry := self._get(ring)) is not None:
            token, reply = entry
            owed = self.owed.pop(token, None)
            if owed is not None:
                try:
                    owed[0].send_multipart([*owed[1], reply], zmq.NOBLOCK)
                except zmq.ZMQError:
                    pass  # the peer is gone or not reading: its loss

    def _publish(self) -> bool:
        """Pass the telemetry on; False at the END of the stream."""
        ring, pub = self.rings["telemetry"], self.sockets["telemetry"]
        while (entry := self._get(ring)) is not None:
            tag, body = entry
            if tag == END:
                return False
            if tag >= len(TOPICS):
                self._bad(tag, "unknown topic")
                continue
            topic = TOPICS[tag]
            if topic == b"event":
                body = self._renumber(body)
            try:
                pub.send_multipart((topic, to_payload(topic, body)))  # PUB drops at a subscriber's high-water mark
            except (struct.error, IndexError) as exc:
                self._bad(tag, str(exc))
        return True

    def _renumber(self, body: bytes) -> bytes:
        """A loop event, its seq moved past the messenger's own events (events are rare)."""
        try:
            event = msgpack.unpackb(body, raw=False)
        except Exception:
            return body
        event["seq"] += self._injected
        self._event_seq = event["seq"]
        return msgpack.packb(event) if self._injected else body

    @staticmethod
    def _get(ring: Ring) -> tuple[int, bytes] | None:
        """The next entry; a ring that cannot be read is emptied (said loudly), not a crash
        that the next messenger would repeat."""
        try:
            return ring.get()
        except RingError as exc:
            ring.discard()
            print(f"pneumad messenger: {exc}; emptied it", file=sys.stderr, flush=True)
            return None

    @staticmethod
    def _bad(tag: int, why: str) -> None:
        """Only the loop writes the telemetry ring: a bad entry is a bug, said loudly, and skipped."""
        print(f"pneumad messenger: dropped a telemetry entry (tag {tag}): {why}", file=sys.stderr, flush=True)


def _request_id(request: bytes):
    """A request's id as the loop would echo it (None if it cannot be read), for a reply the
    messenger gives itself."""
    try:
        return protocol.decode_request(request)["id"]
    except protocol.ProtocolError as exc:
        return exc.request_id


if __name__ == "__main__":
    sys.exit(main())
