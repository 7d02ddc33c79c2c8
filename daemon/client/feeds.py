"""A client's telemetry: a subscription to the daemon's topics (messages as dicts, lost ones
counted by sequence), and the newest cycle record one brings, read by field name through the
daemon's cycle record layout (:meth:`daemon.client.client.Client.layout`)."""
from __future__ import annotations

import collections
import time

import msgpack
import zmq

HEARD_TOPIC = b"stats"  # published once a second: Subscription.wait_until_heard's sign


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
        self.topics = tuple(bytes(t) for t in topics)
        for topic in sorted(self.topics, key=lambda t: t == HEARD_TOPIC):  # stats last: wait_until_heard
            self.sock.setsockopt(zmq.SUBSCRIBE, topic)
        self.sock.connect(endpoint)
        self.last_seq: dict[bytes, int] = {}
        self.lost = 0
        self._held: collections.deque = collections.deque()  # messages read while waiting to be heard

    def wait_until_heard(self, limit_s: float = 30.0) -> None:
        """Return once the daemon's publisher has this subscription. A ZeroMQ publisher drops
        what it sends before a new subscription reaches it and cannot say when one has (the
        "slow joiner"), so an event published just after ``subscribe`` can be missed. The
        subscriptions travel in order on the connection, and ``stats`` (once a second) is
        subscribed last: its first message proves the others arrived. Messages read meanwhile
        are kept for :meth:`receive`; ``stats`` is dropped again unless it was asked for.
        TimeoutError after ``limit_s`` (the daemon's loop publishes no ``stats`` while stalled)."""
        wanted = any(HEARD_TOPIC.startswith(t) for t in self.topics)
        if not wanted:
            self.sock.setsockopt(zmq.SUBSCRIBE, HEARD_TOPIC)
        deadline = time.monotonic() + limit_s
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    raise TimeoutError(f"no stats message from the daemon within {limit_s:g} s: "
                                       "the subscription may not have reached its publisher")
                if not self.sock.poll(left * 1e3):
                    continue
                frames = self.sock.recv_multipart()
                if wanted or frames[0] != HEARD_TOPIC:
                    self._held.append(frames)
                if frames[0] == HEARD_TOPIC:
                    return
        finally:
            if not wanted:
                self.sock.setsockopt(zmq.UNSUBSCRIBE, HEARD_TOPIC)

    def receive(self, timeout: float = 1.0):
        """The next (topic, message), or None after ``timeout`` seconds."""
        if self._held:
            topic, payload = self._held.popleft()
        elif not self.sock.poll(timeout * 1e3):
            return None
        else:  # (a stats message still queued once wait_until_heard unsubscribed: ZeroMQ drops it)
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
