"""A client's telemetry: a subscription to the daemon's topics (messages as dicts, lost ones
counted by sequence), and the newest cycle record one brings, read by field name through the
daemon's cycle record layout (:meth:`daemon.client.client.Client.layout`)."""
from __future__ import annotations

import time

import msgpack
import zmq


class LatestState:
    """The newest cycle record a ``state`` subscription has brought, by field name (SI values,
    ``mode`` by name), through the daemon's layout (:meth:`Client.layout`)."""

    def __init__(self, client):
        self.client = client
        self.sub = client.subscribe((b"state",))
        self.last: dict | None = None

    def row(self, timeout: float | None = None) -> dict:
        """The newest record received so far (every message waiting read first); the first waits
        up to ``timeout`` (the client's by default) for a message: TimeoutError if none comes."""
        limit = self.client.timeout if timeout is None else timeout
        deadline = time.monotonic() + limit
        wait = 0.0 if self.last is not None else limit
        while True:
            got = self.sub.receive(wait)
            if got is None:
                if self.last is not None:
                    return self.last
                if time.monotonic() >= deadline:
                    raise TimeoutError(f"no state message from {self.client.endpoints['telemetry']} within {limit:g} s")
                wait = max(deadline - time.monotonic(), 0.0)
                continue
            layout = self.client.layout(got[1])
            if got[1].get("layout") == layout.id:
                self.last = {name: got[1][name][-1] for name in layout.names}
            wait = 0.0 if self.last is not None else max(deadline - time.monotonic(), 0.0)

    def close(self) -> None:
        self.sub.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Subscription:
    """Telemetry messages as (topic, dict), with a count of messages lost (by sequence)."""

    def __init__(self, context: zmq.Context, endpoint: str, topics, secure=None):
        self.sock = context.socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        if secure is not None:
            secure(self.sock)
        self.sock.setsockopt(zmq.RCVHWM, 100000)
        for topic in topics:
            self.sock.setsockopt(zmq.SUBSCRIBE, topic)
        self.sock.connect(endpoint)
        self.last_seq: dict[bytes, int] = {}
        self.lost = 0

    def receive(self, timeout: float = 1.0):
        """The next (topic, message), or None after ``timeout`` seconds."""
        if not self.sock.poll(timeout * 1e3):
            return None
        topic, payload = self.sock.recv_multipart()
        message = msgpack.unpackb(payload, raw=False)
        seq = message.get("seq")
        last = self.last_seq.get(topic)
        if last is not None and seq is not None and seq > last + 1:
            self.lost += seq - last - 1
        self.last_seq[topic] = seq
        return topic.decode(), message

    def close(self) -> None:
        self.sock.close(linger=0)
