"""The messenger's side of the model process (:mod:`daemon.model.process`, met through
:mod:`daemon.wire.helper_links`): every ``state`` message handed on as it is published (a PUSH
that drops when the model process is behind or restarting: it starts its models again at the
gap), and what it sends back published: the ``model`` topic (to subscribers, the recorder and
the Foxglove stream) and its events. Both sockets are bound here, so a restarted model
process connects to the same ones."""
from __future__ import annotations

import msgpack
import zmq

from daemon.wire.helper_links import EVENT, HELPER_TOPICS, MODEL_FEED, MODEL_FEED_HWM, MODEL_OUT, endpoint


class ModelLink:
    def __init__(self, ctx: zmq.Context, rings_dir: str):
        self.feed_socket = ctx.socket(zmq.PUSH)
        self.feed_socket.setsockopt(zmq.SNDHWM, MODEL_FEED_HWM)
        self.out = ctx.socket(zmq.PULL)
        for sock in (self.feed_socket, self.out):
            sock.setsockopt(zmq.LINGER, 0)
        self.feed_socket.bind(endpoint(rings_dir, MODEL_FEED))
        self.out.bind(endpoint(rings_dir, MODEL_OUT))
        self.dropped = 0

    def feed(self, payload: bytes) -> None:
        """A ``state`` message's payload, as published (b"" ends the model process's feed)."""
        try:
            self.feed_socket.send_multipart((b"state" if payload else b"", payload), zmq.NOBLOCK)
        except zmq.Again:
            self.dropped += 1  # the model process sees the gap in the cycles

    def take(self, publish, publish_event) -> None:
        """What the model process sent: ``publish(topic, payload)`` for the ``model`` topic,
        ``publish_event(event)`` for its events."""
        while True:
            try:
                topic, body = self.out.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            except ValueError:
                continue
            if topic in HELPER_TOPICS:
                publish(topic, body)
            elif topic == EVENT:
                try:
                    publish_event(msgpack.unpackb(body, raw=False))
                except ValueError:
                    pass

    def close(self) -> None:
        self.feed_socket.close()
        self.out.close()
