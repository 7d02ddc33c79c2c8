"""A real Foxglove WebSocket client for tests and benches (the `websockets` package speaking
the protocol foxglove-sdk serves): the server's advertisements, subscriptions, and binary
``messageData`` frames decoded against each channel's advertised schema and encoding (JSON, or
protobuf through the advertised FileDescriptorSet). Nothing of the daemon's own code decodes.

foxglove-sdk 0.30 serves the subprotocol ``foxglove.sdk.v1`` (and refuses the older
``foxglove.websocket.v1`` with HTTP 400); the messages themselves are the ws-protocol's: JSON
``serverInfo``/``advertise``/``subscribe``, binary opcode 1 = message data (subscription id
uint32, log time uint64 [ns], payload), little-endian.

``stalled=True`` makes a client that stops reading after the handshake: a one-frame receive
queue (websockets then stops reading the socket) and a small receive buffer, so the server's
sends to it back up, as with a laptop on a dead link.
"""
from __future__ import annotations

import base64
import json
import socket
import struct
import time

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 1
_HEADER = struct.Struct("<BIQ")


def _connection(port: int, stalled: bool, limit_s: float) -> ClientConnection:
    """Connect, retrying until the server listens (a daemon starting up) or ``limit_s`` ends."""
    deadline = time.monotonic() + limit_s
    while True:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if stalled:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        try:
            sock.connect(("127.0.0.1", port))
            return connect(f"ws://127.0.0.1:{port}", sock=sock, subprotocols=[SUBPROTOCOL],
                           max_queue=(1, 0) if stalled else 4096, max_size=None, open_timeout=limit_s, legacy=True,
                           ping_interval=None)  # a stalled client reads no pong: no keepalive to time out
        except OSError:
            sock.close()
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


class FoxgloveClient:
    def __init__(self, port: int, stalled: bool = False, limit_s: float = 60.0):
        self.ws = _connection(port, stalled, limit_s)
        self.server_info: dict = {}
        self.channels: dict[str, dict] = {}  # topic -> its advertisement
        self._subscribed: dict[int, dict] = {}  # subscription id -> channel
        self._decoders: dict[int, object] = {}

    def advertised(self, topics=(), limit_s: float = 60.0) -> dict[str, dict]:
        """The channels advertised so far, reading until every one of ``topics`` is among them."""
        deadline = time.monotonic() + limit_s
        while not set(topics) <= set(self.channels):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"not advertised within {limit_s} s: {sorted(set(topics) - set(self.channels))}")
            self._take(self.ws.recv(timeout=remaining))
        return self.channels

    def subscribe(self, topics) -> None:
        subscriptions = []
        for topic in topics:
            sid = len(self._subscribed) + 1
            self._subscribed[sid] = self.channels[topic]
            subscriptions.append({"id": sid, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def receive(self, limit_s: float = 10.0) -> tuple[str, int, object] | None:
        """The next message on a subscribed channel: (topic, log time [ns], decoded message),
        or None if none came within ``limit_s``."""
        deadline = time.monotonic() + limit_s
        while (remaining := deadline - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=remaining)
            except TimeoutError:
                return None
            if isinstance(frame, str):
                self._take(frame)
                continue
            opcode, sid, log_time = _HEADER.unpack_from(frame)
            if opcode == MESSAGE_DATA and sid in self._subscribed:
                channel = self._subscribed[sid]
                return channel["topic"], log_time, self.decode(sid, frame[_HEADER.size:])
        return None

    def decode(self, sid: int, payload: bytes):
        channel = self._subscribed[sid]
        if channel["encoding"] == "json":
            return json.loads(payload)
        if channel["encoding"] != "protobuf":
            raise ValueError(f"{channel['topic']}: encoding {channel['encoding']!r}")
        if sid not in self._decoders:
            self._decoders[sid] = protobuf_class(channel["schemaName"], base64.b64decode(channel["schema"]))
        return self._decoders[sid].FromString(payload)

    def _take(self, text: str) -> None:
        message = json.loads(text)
        if message.get("op") == "serverInfo":
            self.server_info = message
        elif message.get("op") == "advertise":
            self.channels.update({c["topic"]: c for c in message["channels"]})

    def close(self) -> None:
        self.ws.close()


def protobuf_class(name: str, descriptor_set: bytes):
    """The message class of ``name`` in a serialised FileDescriptorSet (as advertised)."""
    files = list(descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file)
    pool = descriptor_pool.DescriptorPool()
    while files:  # dependencies first, whatever order the set lists them in
        added = [f for f in files if all(pool_has(pool, d) for d in f.dependency)]
        if not added:
            raise ValueError(f"{name}: unresolved imports in its schema")
        for f in added:
            pool.Add(f)
            files.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def pool_has(pool, filename: str) -> bool:
    try:
        pool.FindFileByName(filename)
        return True
    except KeyError:
        return False
