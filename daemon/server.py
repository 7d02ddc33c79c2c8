"""ZeroMQ endpoints: the command socket, the control socket and the telemetry publisher.

All socket work the loop does is non-blocking and bounded: each cycle it serves every
pending message on the control socket (e-stop, abort, disable, status, ping; at most
``MAX_CONTROL_PER_CYCLE``), then at most ``max_per_cycle`` requests on the command socket.
The control socket is separate so an e-stop never queues behind other requests. ZeroMQ's
own I/O threads (C, outside the GIL) do the network work. Frames over
``protocol.MAX_MESSAGE_BYTES`` are refused by ZeroMQ itself (the peer is disconnected).
"""
from __future__ import annotations

import zmq

from daemon import protocol
from daemon.commands import Commands
from daemon.preparation import Deferred

DEFAULT_COMMAND = "tcp://127.0.0.1:5560"
DEFAULT_CONTROL = "tcp://127.0.0.1:5561"
DEFAULT_TELEMETRY = "tcp://127.0.0.1:5562"
MAX_CONTROL_PER_CYCLE = 8
TELEMETRY_HWM = 1000  # messages queued per subscriber before ZeroMQ drops (100 ms of state batches)


class ZmqServer:
    def __init__(self, command: str = DEFAULT_COMMAND, control: str = DEFAULT_CONTROL,
                 telemetry: str = DEFAULT_TELEMETRY, max_per_cycle: int = 2, context: zmq.Context | None = None):
        self.context = context or zmq.Context.instance()
        self.max_per_cycle = max_per_cycle
        self.cmd = self._router(command)
        self.ctl = self._router(control)
        self.pub = self.context.socket(zmq.PUB)
        self.pub.setsockopt(zmq.SNDHWM, TELEMETRY_HWM)
        self.pub.setsockopt(zmq.LINGER, 0)
        self.pub.bind(telemetry)
        self.endpoints = {name: sock.getsockopt_string(zmq.LAST_ENDPOINT)
                          for name, sock in (("command", self.cmd), ("control", self.ctl), ("telemetry", self.pub))}
        self.commands: Commands | None = None
        self._waiting: list[tuple[zmq.Socket, list, Deferred]] = []  # replies owed once work is done
        self.reply_failures = 0
        self.published = 0

    def _router(self, endpoint: str) -> zmq.Socket:
        sock = self.context.socket(zmq.ROUTER)
        sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_MESSAGE_BYTES)
        sock.setsockopt(zmq.RCVHWM, 1000)
        sock.setsockopt(zmq.SNDHWM, 1000)
        sock.setsockopt(zmq.LINGER, 0)
        sock.bind(endpoint)
        return sock

    def attach(self, loop, preparer=None) -> None:
        self.commands = Commands(loop, preparer)
        loop.server = self

    def publish(self, topic: bytes, payload: bytes) -> None:
        """Send without blocking; a PUB socket drops for subscribers at their high-water mark."""
        try:
            self.pub.send_multipart((topic, payload), zmq.NOBLOCK)
            self.published += 1
        except zmq.ZMQError:
            pass

    def poll(self, loop) -> None:
        """Once a cycle, at its end: the lease clock, then the control socket, then a few commands."""
        self.commands.tick()
        if self._waiting:
            self._complete()
        self._serve(self.ctl, True, MAX_CONTROL_PER_CYCLE)
        self._serve(self.cmd, False, self.max_per_cycle)

    def _complete(self) -> None:
        """Reply to deferred commands whose work is done (applying it at this boundary)."""
        for item in [w for w in self._waiting if w[2].future.done()]:
            self._waiting.remove(item)
            sock, envelope, deferred = item
            self._send(sock, envelope, self.commands.complete(deferred))

    def _serve(self, sock: zmq.Socket, control: bool, limit: int) -> None:
        for _ in range(limit):
            # asking for EVENTS costs a third of a failed non-blocking receive (no exception)
            if not sock.getsockopt(zmq.EVENTS) & zmq.POLLIN:
                return
            try:
                frames = sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            reply = self.commands.handle_payload(frames[-1], control)
            if isinstance(reply, Deferred):
                self._waiting.append((sock, frames[:-1], reply))
            else:
                self._send(sock, frames[:-1], reply)

    def _send(self, sock: zmq.Socket, envelope: list, reply: bytes) -> None:
        try:
            sock.send_multipart([*envelope, reply], zmq.NOBLOCK)
        except zmq.ZMQError:
            self.reply_failures += 1  # the peer is gone or not reading: its loss, not the loop's

    def close(self) -> None:
        if self.commands is not None:
            self.commands.preparer.close()
        for sock in (self.cmd, self.ctl, self.pub):
            sock.close(linger=0)
