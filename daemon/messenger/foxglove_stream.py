"""The live Foxglove stream (``pneumad run --foxglove HOST:PORT``): the Foxglove WebSocket
protocol (foxglove.websocket.v1, served by foxglove-sdk) with the channels of
:mod:`daemon.recordings.channels`, the same the recordings hold, so one layout serves both.

It runs in the messenger process, from the telemetry the messenger already decoded: the loop
never knows. Read-only: it advertises channels and nothing else (no parameters, services or
client publishing); commands stay on the ZeroMQ sockets. Nothing is encoded for a channel no
client subscribed to. The SDK's server sends from threads of its own with a bounded queue per
client (``BACKLOG`` messages) that drops the oldest when a client is slow, and disconnects a
client whose control messages back up: a slow or stalled client loses its own messages, never
anyone else's, and the relay never waits on it (``log`` only queues).

The protocol has no CURVE: the address must be loopback (from a laptop, ``ssh -L
8765:127.0.0.1:8765 LAB-PC``, then connect Foxglove to ``ws://localhost:8765``) unless the
daemon runs ``--insecure`` (checked by :func:`daemon.loop.port.foxglove_address`).
"""
from __future__ import annotations

import json
import os
import sys

import foxglove

from daemon.recordings.channels import (
    CONTACT,
    CONTROLLER,
    LOOP,
    Frames,
    json_schemas,
    protobuf_schemas,
    schema_name,
)

BACKLOG = 20_000  # messages queued per client before the oldest are dropped (about 3 s of every channel)


class FoxgloveStream:
    def __init__(self, host: str, port: int, rings_dir: str):
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name="pneumad", host=host, port=port, context=self.context,
                                            message_backlog_size=BACKLOG)  # RuntimeError if it cannot bind
        self._rings_dir = rings_dir
        self._frames: Frames | None = None
        self.channels: dict[str, foxglove.Channel] = {}

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
        """One telemetry message as subscribers see it (``state`` columns, ``event`` ...)."""
        if not self._ready():
            return
        try:
            if topic == "state":
                wanted = {t for t, ch in self.channels.items() if ch.has_sinks()}
                frames = self._frames.state(message, wanted) if wanted else ()
            elif topic == "event" or self._wanted(topic):
                frames = self._frames.of(topic, message)  # events always: a reference's span is followed
            else:
                return
            for channel, stamp, data in frames:
                self.channels[channel].log(data, log_time=stamp)
        except Exception as exc:  # only the loop writes the telemetry: a bug, said loudly, never fatal
            print(f"pneumad messenger: no Foxglove message for a {topic} message: {exc!r}", file=sys.stderr, flush=True)

    def _wanted(self, topic: str) -> bool:
        channel = self.channels.get(_CHANNEL_OF.get(topic, ""))
        return channel is not None and channel.has_sinks()

    def close(self) -> None:
        self.server.stop()


_CHANNEL_OF = {"internals": CONTROLLER, "stats": LOOP, "contact": CONTACT}  # telemetry topic -> its one channel
