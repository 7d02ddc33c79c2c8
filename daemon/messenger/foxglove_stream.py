"""The live Foxglove stream (``pneumad run --foxglove HOST:PORT``): the Foxglove WebSocket
protocol (served by foxglove-sdk 0.30, subprotocol ``foxglove.sdk.v1``) with the channels of
:mod:`daemon.recordings.channels`, the same the recordings hold, so one layout serves both.

It runs in the messenger process, from the telemetry the messenger already decoded: the loop
never knows. Read-only: it advertises channels and nothing else (no parameters, services or
client publishing); commands stay on the ZeroMQ sockets. Nothing is encoded for a channel no
client subscribed to. The SDK's server sends from threads of its own with a bounded queue per
client (``BACKLOG`` messages) that drops the oldest when a client is slow, and disconnects a
client whose control messages back up: a slow or stalled client loses its own messages, never
anyone else's, and the relay never waits on it (``log`` only queues).

The encoding (about 100 us of Python a cycle when every channel is subscribed) is done in
slices between the relay's socket work (:meth:`FoxgloveStream.work`), so a command's round trip
waits for a slice, not for a batch; and from a bounded queue, so a messenger that cannot keep
up (a starved machine) drops Foxglove's oldest messages, never the relay's telemetry.

The protocol has no CURVE: the address must be loopback (from a laptop, ``ssh -L
8765:127.0.0.1:8765 LAB-PC``, then connect Foxglove to ``ws://localhost:8765``) unless the
daemon runs ``--insecure`` (checked by :func:`daemon.loop.port.foxglove_address`).

A viewer that offers only the older subprotocol ``foxglove.websocket.v1`` (Foxglove Studio
1.x, Lichtblick before 1.22.1) is refused by the SDK with a bare HTTP 400, which it logs as
"handshake failed" and nothing more (it has no hook for it): :class:`HandshakeAdvice` adds
the likely cause and the fix to that log line.
"""
from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections import deque

import foxglove

from daemon.recordings.channels import (
    CONTACT,
    CONTROLLER,
    LOOP,
    MODEL,
    Frames,
    json_schemas,
    protobuf_schemas,
    schema_name,
)

BACKLOG = 20_000  # messages queued per client before the oldest are dropped (about 3 s of every channel)
PENDING = 1000  # telemetry messages waiting to be encoded (10 s of state batches) before the oldest are dropped
SLICE_S = 2e-4  # encoding done at a time before the relay looks at its sockets again [s]


SUBPROTOCOL = "foxglove.sdk.v1"  # the one foxglove-sdk 0.30 speaks (and refuses any other)
ADVICE = (f"a Foxglove viewer's WebSocket handshake was refused (HTTP 400): this server speaks only the subprotocol "
          f"{SUBPROTOCOL}, and a viewer that offers only foxglove.websocket.v1 (Foxglove Studio 1.x, Lichtblick before "
          f"1.22.1) is refused: use Lichtblick 1.22.1 or later, or a current Foxglove app (docs/protocol.md, Foxglove)")


class HandshakeAdvice(logging.Filter):
    """foxglove-sdk logs a refused handshake ("Dropping client ADDR: handshake failed") through
    Python's logging, without the subprotocol the client offered: the line gets the likely
    cause and the fix."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if message.endswith("handshake failed"):
            record.msg, record.args = f"{message}; {ADVICE}", ()
        return True


_ADVICE = HandshakeAdvice()


class FoxgloveStream:
    def __init__(self, host: str, port: int, rings_dir: str):
        logging.getLogger("foxglove.websocket.server").addFilter(_ADVICE)  # the SDK's server logs there
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name="pneumad", host=host, port=port, context=self.context,
                                            message_backlog_size=BACKLOG)  # RuntimeError if it cannot bind
        self._rings_dir = rings_dir
        self._frames: Frames | None = None
        self.channels: dict[str, foxglove.Channel] = {}
        self.pending: deque[list] = deque(maxlen=PENDING)  # [topic, message, next row of a state batch]
        self.dropped = 0  # telemetry messages the stream could not keep up with

    def _ready(self) -> bool:
        """The channels, made once the daemon's describe is there (written before its first cycle)."""
        if self._frames is None:
            try:
                with open(os.path.join(self._rings_dir, "describe.json")) as f:
                    describe = json.load(f)
            except (OSError, ValueError):
                return False
            self._frames = Frames(describe)
            for topic, schema in json_schemas(describe).items():
                self.channels[topic] = foxglove.Channel(
                    topic, schema=foxglove.Schema(name=schema_name(topic), encoding="jsonschema",
                                                  data=json.dumps(schema).encode()),
                    message_encoding="json", context=self.context)
            for topic, (name, data) in protobuf_schemas().items():
                self.channels[topic] = foxglove.Channel(
                    topic, schema=foxglove.Schema(name=name, encoding="protobuf", data=data),
                    message_encoding="protobuf", context=self.context)
        return True

    def take(self, topic: str, message: dict) -> None:
        """Queue one telemetry message as subscribers see it (``state`` columns, ``event`` ...)
        for :meth:`work`; nothing when no client wants it (events always: a reference's span
        is followed). The queue keeps the newest ``PENDING`` messages: a messenger that cannot
        keep up loses Foxglove's share, never the relay's."""
        if not self._ready() or not (topic == "event" or self._wanted(topic)):
            return
        if len(self.pending) == self.pending.maxlen:
            self.dropped += 1
        self.pending.append([topic, message, 0])

    @property
    def busy(self) -> bool:
        return bool(self.pending)

    def work(self, budget_s: float = SLICE_S) -> None:
        """Encode and send queued messages, a cycle of a ``state`` batch at a time, for about
        ``budget_s``: the relay goes back to its sockets in between, so a request or a reply
        waits for one slice at most, not for a batch's encoding."""
        start = time.perf_counter()
        while self.pending and time.perf_counter() - start < budget_s:
            item = self.pending[0]
            topic, message, row = item
            try:
                if topic == "state":
                    wanted = {t for t, ch in self.channels.items() if ch.has_sinks()}
                    frames = self._frames.state(message, wanted, (row,)) if wanted else ()
                    item[2] = row = row + 1
                    done = not wanted or row >= len(message["cycle"])
                else:
                    frames, done = self._frames.of(topic, message), True
                for channel, stamp, data in frames:
                    self.channels[channel].log(data, log_time=stamp)
            except Exception as exc:  # only the loop writes the telemetry: a bug, said loudly, never fatal
                print(f"pneumad messenger: no Foxglove message for a {topic} message: {exc!r}", file=sys.stderr,
                      flush=True)
                done = True
            if done:
                self.pending.popleft()

    def _wanted(self, topic: str) -> bool:
        if topic == "state":
            return any(ch.has_sinks() for ch in self.channels.values())
        channel = self.channels.get(_CHANNEL_OF.get(topic, ""))
        return channel is not None and channel.has_sinks()

    def close(self) -> None:
        self.server.stop()


_CHANNEL_OF = {"internals": CONTROLLER, "stats": LOOP, "contact": CONTACT, "model": MODEL}  # telemetry topic -> its one channel
