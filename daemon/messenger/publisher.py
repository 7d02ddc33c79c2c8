"""The messenger's telemetry out (:class:`Publisher`): each entry of the loop's telemetry ring made a
message (a state batch read by the cycle layout, stats summarised, internals decoded), published on
the PUB socket and handed on to the recorder, the model process, PlotJuggler and the Foxglove
stream; events (the loop's, and those of the messenger and its helpers) numbered in one sequence,
named with their flight file and written to the daemon's journal. :mod:`daemon.messenger.relay`
owns it and calls it between its requests."""
from __future__ import annotations

import struct
import sys
import time
from typing import TYPE_CHECKING, Callable

import msgpack
import zmq

from daemon.messenger.journal import Journal
from daemon.messenger.model_link import ModelLink
from daemon.messenger.plotjuggler import PlotJugglerFeed
from daemon.messenger.recorder_link import Recorder
from daemon.messenger.shared import END, TOPICS, ring_entry
from daemon.wire.cycle_layout import CycleLayout
from daemon.wire.flight import FlightNames
from daemon.wire.loop_stats import StatsBanks, summarise
from daemon.wire.ring import Ring
from daemon.wire.telemetry_rows import internals_message, state_message

if TYPE_CHECKING:  # imported where the stream is asked for (daemon.messenger.process): the SDK costs start-up time
    from daemon.messenger.foxglove_stream import FoxgloveStream


class Publisher:
    """The telemetry socket (in ``sockets``, which the relay binds again after a key's removal)
    and everything that takes telemetry beside it."""

    def __init__(self, sockets: dict[str, zmq.Socket], ring: Ring, layout: CycleLayout, stats: StatsBanks,
                 take_stats: Callable[[dict], None], journal: Journal, flights: FlightNames | None,
                 recorder: Recorder | None, model: ModelLink | None, plotjuggler: PlotJugglerFeed | None,
                 foxglove: FoxgloveStream | None):
        self.sockets, self.ring = sockets, ring
        self.layout = layout  # the cycle record's: how a state batch reads
        self.stats = stats  # the loop's timing histograms, summarised here once a window
        self.take_stats = take_stats  # each summary, to the timing judge
        self.journal = journal  # every event published, a line of the daemon's log
        self.flights = flights  # a trip's flight file, named as its event goes out (daemon.wire.flight)
        self.recorder, self.model, self.plotjuggler = recorder, model, plotjuggler
        self.foxglove = foxglove  # the live Foxglove stream (daemon.messenger.foxglove_stream)
        self._event_seq = 0  # the last event seq sent
        self._injected = 0  # events of the messenger's own so far: loop events are renumbered after them

    def event(self, event: dict, source: str, cycle: int) -> None:
        """Publish an event of the messenger's own (or the recorder's, or the model process's),
        numbered in the loop's event sequence; ``cycle``: the loop's last seen, unless it names one."""
        self._injected += 1
        self._event_seq += 1
        event = {"t": time.monotonic(), "cycle": cycle, **event, "seq": self._event_seq, "source": source}
        self._name_flight(event)
        self.journal.write(event)
        body = msgpack.packb(event)
        self.sockets["telemetry"].send_multipart((b"event", body))
        if self.recorder is not None:
            self.recorder.feed(b"event", body)
        if self.foxglove is not None:
            self.foxglove.take("event", msgpack.unpackb(body, raw=False))

    def drain(self) -> bool:
        """Pass the telemetry ring's entries on; False at the END of the stream."""
        ring, pub = self.ring, self.sockets["telemetry"]
        while (entry := ring_entry(ring)) is not None:
            tag, body = entry
            if tag == END:
                if self.recorder is not None:
                    self.recorder.feed(b"", b"")  # the recorder finishes its files
                if self.model is not None:
                    self.model.feed(b"")
                return False
            if tag >= len(TOPICS):
                self._bad(tag, "unknown topic")
                continue
            topic = TOPICS[tag]
            if topic == b"event":
                body = self._renumber(body)
            try:
                columns = state_message(self.layout, body) if topic == b"state" else None
                if topic == b"stats":
                    summary = summarise(self.stats, body)
                    body = msgpack.packb(summary)
                    self.take_stats(summary)
                elif topic == b"internals":
                    body = msgpack.packb(internals_message(body))
            except (struct.error, IndexError, ValueError) as exc:
                self._bad(tag, str(exc))
                continue
            payload = msgpack.packb(columns) if columns is not None else body
            pub.send_multipart((topic, payload))  # PUB drops at a subscriber's high-water mark
            if self.recorder is not None:
                self.recorder.feed(topic, payload)
            if self.model is not None and columns is not None:
                self.model.feed(payload)
            if self.plotjuggler is not None:
                self._plot(topic, columns, body)
            if self.foxglove is not None:
                self._stream(topic, columns, body)
        return True

    def model_message(self, topic: bytes, payload: bytes) -> None:
        """The model process's ``model`` message, published as the loop's topics are."""
        self.sockets["telemetry"].send_multipart((topic, payload))
        if self.recorder is not None:
            self.recorder.feed(topic, payload)
        if self.foxglove is not None:
            self.foxglove.take("model", msgpack.unpackb(payload, raw=False))

    def _stream(self, topic: bytes, columns: dict | None, body: bytes) -> None:
        """The live Foxglove stream's share (:mod:`daemon.messenger.foxglove_stream`)."""
        if columns is not None:
            self.foxglove.take("state", columns)
            return
        try:
            message = msgpack.unpackb(body, raw=False)
        except Exception as exc:  # only the loop writes these: a bug, said loudly, never fatal
            print(f"pneumad messenger: cannot read a {topic.decode()} message for Foxglove: {exc}", file=sys.stderr,
                  flush=True)
            return
        self.foxglove.take(topic.decode(), message)

    def _plot(self, topic: bytes, columns: dict | None, body: bytes) -> None:
        """The rows PlotJuggler plots (:mod:`daemon.messenger.plotjuggler`)."""
        if columns is not None:
            self.plotjuggler.state(columns)
        elif topic in (b"internals", b"stats"):
            try:
                message = msgpack.unpackb(body, raw=False)
                (self.plotjuggler.internals if topic == b"internals" else self.plotjuggler.stats)(message)
            except Exception as exc:  # only the loop writes these: a bug, said loudly, never fatal
                print(f"pneumad messenger: no PlotJuggler row for a {topic.decode()} message: {exc}", file=sys.stderr,
                      flush=True)

    def _renumber(self, body: bytes) -> bytes:
        """A loop event, its seq moved past the messenger's own events (events are rare), and
        written to the journal."""
        try:
            event = msgpack.unpackb(body, raw=False)
        except Exception:
            return body
        named = self._name_flight(event)
        self.journal.write(event)
        event["seq"] += self._injected
        self._event_seq = event["seq"]
        return msgpack.packb(event) if self._injected or named else body

    def _name_flight(self, event: dict) -> bool:
        """A trip's, an e-stop's or a stall's event gets the ``flight`` field: the file the recorder
        writes its last seconds to (its journal line names it too). Whether it did."""
        name = self.flights.name_for(event) if self.flights is not None else None
        if name is not None:
            event["flight"] = name
        return name is not None

    @staticmethod
    def _bad(tag: int, why: str) -> None:
        """Only the loop writes the telemetry ring: a bad entry is a bug, said loudly, and skipped."""
        print(f"pneumad messenger: dropped a telemetry entry (tag {tag}): {why}", file=sys.stderr, flush=True)
