"""The messenger's side of the recorder (:mod:`daemon.recorder.process`, met through
:mod:`daemon.wire.helper_links`): every telemetry message
handed on as it leaves the loop's ring, ``record.*`` requests passed over (each after a mark on
the feed, up to which the recorder takes in the telemetry before it answers) and their answers
passed back, and the recorder's events published.

Nothing here waits: the feed is a PUSH that drops (and counts) when the recorder's queue is
full or no recorder is connected (one restarting), which the recording then shows as a gap; a
request the recorder has not answered in ``ANSWER_TIMEOUT_S`` is answered ``recorder_unavailable``.

The messenger binds the feed and the recorder connects to it: a connecting ZeroMQ socket keeps
one queue across its peer's restarts, so what a killed messenger sent and the recorder has not
yet read comes before what the next messenger sends. Bound on the recorder's side, the two
messengers' queues were read in turns, and a recording made across a messenger restart held
messages out of time order.
"""
from __future__ import annotations

import json
import struct
import time

import zmq

from daemon.messenger.shared import CLOSE_LINGER_MS
from daemon.wire import protocol
from daemon.wire.helper_links import (EVENT, MARK, MESSENGER_ID, RECORDER_CONTROL, RECORDER_FEED, RECORDER_FEED_HWM,
                                      REPLY, endpoint)

ANSWER_TIMEOUT_S = 5.0
_TOKEN = struct.Struct("<Q")


class Recorder:
    def __init__(self, ctx: zmq.Context, rings_dir: str):
        self.feed_socket = ctx.socket(zmq.PUSH)
        self.feed_socket.setsockopt(zmq.SNDHWM, RECORDER_FEED_HWM)
        self.control = ctx.socket(zmq.DEALER)
        self.control.setsockopt(zmq.ROUTING_ID, MESSENGER_ID)
        for sock in (self.feed_socket, self.control):
            sock.setsockopt(zmq.LINGER, 0)
        self.feed_socket.bind(endpoint(rings_dir, RECORDER_FEED))  # (a killed messenger's socket file is replaced)
        self.control.connect(endpoint(rings_dir, RECORDER_CONTROL))
        self.owed: dict[int, tuple[zmq.Socket, list, float, object]] = {}  # token -> (socket, envelope, when, id)
        self.dropped = 0

    def feed(self, topic: bytes, payload: bytes) -> None:
        try:
            self.feed_socket.send_multipart((topic, payload), zmq.NOBLOCK)
        except zmq.Again:
            self.dropped += 1  # the recording shows it as a gap in the topic's seq

    def ask(self, token: int, sock: zmq.Socket, envelope: list, body: bytes, request_id, who: str) -> bool:
        """Pass a request on (already checked against the catalog); False if the recorder
        cannot take it now."""
        packed = _TOKEN.pack(token)
        self.feed(MARK, packed)  # in the feed's order: the recorder takes in what came before it
        try:
            self.control.send_multipart((packed, who.encode(), body), zmq.NOBLOCK)
        except zmq.Again:
            return False
        self.owed[token] = (sock, envelope, time.monotonic(), request_id)
        return True

    def take_answers(self, publish_event) -> None:
        """The recorder's replies (to their clients) and events (published by ``publish_event``)."""
        while True:
            try:
                frames = self.control.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if frames[0] == REPLY and len(frames) == 3:
                owed = self.owed.pop(_TOKEN.unpack(frames[1])[0], None)
                if owed is not None:
                    send_reply(owed[0], owed[1], frames[2])
            elif frames[0] == EVENT and len(frames) == 2:
                try:
                    publish_event(json.loads(frames[1]), "recorder")
                except ValueError:
                    pass

    def expire(self, now: float) -> None:
        for token, (sock, envelope, when, request_id) in list(self.owed.items()):
            if now - when > ANSWER_TIMEOUT_S:
                del self.owed[token]
                send_reply(sock, envelope, protocol.encode_error(
                    request_id, protocol.BAD_STATE, f"the recorder did not answer within {ANSWER_TIMEOUT_S:g} s",
                    {"reason": "recorder_unavailable"}))

    def close(self) -> None:
        """The feed's last messages may take CLOSE_LINGER_MS to leave: the loop's END among
        them, on which the recorder finishes its files (dropped at once, the daemon's stop
        waited 5 s for the recorder, then stopped it with SIGTERM)."""
        self.feed_socket.setsockopt(zmq.LINGER, CLOSE_LINGER_MS)
        self.feed_socket.close()
        self.control.close()


def send_reply(sock: zmq.Socket, envelope: list, reply: bytes) -> None:
    """A reply to a ROUTER's peer, never waiting."""
    try:
        sock.send_multipart([*envelope, reply], zmq.NOBLOCK)
    except zmq.ZMQError:
        pass  # the peer is gone or not reading: its loss
