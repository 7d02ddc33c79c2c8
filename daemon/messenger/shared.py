"""What the messenger's parts share with the loop's side and with each other: the telemetry
ring's topic tags and its END, the loop's heartbeat, the stall default, the sockets as the
messenger opens them, and the SIGHUPs not yet acted on. A leaf of the messenger's folder, so
its handle (:mod:`daemon.messenger.process`) and its relay (:mod:`daemon.messenger.relay`)
import it, never each other."""
from __future__ import annotations

import mmap
import os
import struct
import sys

import zmq

from daemon.messenger.guard import Guard
from daemon.wire import protocol
from daemon.wire.endpoint_holders import held_by
from daemon.wire.ring import Ring, RingError

TOPICS = (b"", b"state", b"stats", b"event", b"internals", b"contact")  # telemetry ring tags; 0 ends the stream
END = 0
TELEMETRY_HWM = 1000  # messages queued per subscriber before ZeroMQ drops (100 ms of state batches)
ROUTER_HWM = 1000
IDLE_POLL_MS = 2  # telemetry waits at most this long in the ring [ms]
OWED_LIMIT_S = 60.0  # a reply owed this long is forgotten (the loop always answers sooner)
STALL_S = 0.5  # a loop whose cycle count has not moved for this long is answered for [s] (default)
CLOSE_LINGER_MS = 500  # how long the last messages may take to leave at exit
_BEAT = struct.Struct("<Q")

reloads: list[int] = []  # SIGHUPs not yet acted on (in the messenger process)


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


def open_socket(ctx: zmq.Context, name: str, endpoint: str, guard: Guard | None) -> zmq.Socket:
    """One of the daemon's sockets, bound (ZMQError if it cannot be: EADDRINUSE, naming who
    holds it, for an endpoint another program listens on, an ``ipc://`` one included)."""
    holder = held_by(endpoint) if endpoint.startswith("ipc://") else ""
    if holder:
        raise zmq.ZMQError(zmq.EADDRINUSE, f"in use by {holder}: another daemon? stop it, or give this one other "
                                           f"endpoints")
    sock = ctx.socket(zmq.PUB if name == "telemetry" else zmq.ROUTER)
    sock.setsockopt(zmq.LINGER, 0)
    if name == "telemetry":
        sock.setsockopt(zmq.SNDHWM, TELEMETRY_HWM)
    else:
        sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_FRAME_BYTES)  # up to it, over-size requests are answered
        sock.setsockopt(zmq.RCVHWM, ROUTER_HWM)
        sock.setsockopt(zmq.SNDHWM, ROUTER_HWM)
    if guard is not None:
        guard.secure(sock)
    try:
        sock.bind(endpoint)
    except zmq.ZMQError as exc:
        sock.close()
        holder = held_by(endpoint) if exc.errno == zmq.EADDRINUSE else ""
        if holder:
            raise zmq.ZMQError(zmq.EADDRINUSE, f"in use by {holder}") from None
        raise
    return sock


def ring_entry(ring: Ring) -> tuple[int, bytes] | None:
    """The next entry; a ring that cannot be read is emptied (said loudly), not a crash
    that the next messenger would repeat."""
    try:
        return ring.get()
    except RingError as exc:
        ring.discard()
        print(f"pneumad messenger: {exc}; emptied it", file=sys.stderr, flush=True)
        return None
