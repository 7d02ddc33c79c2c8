"""The flight recorder, in the recorder process beside the loop: the last seconds of every
telemetry topic held in memory, and written to an MCAP file for each trip, e-stop and stalled
loop (the events the messenger named a file for: :mod:`daemon.wire.flight`) and on request
(``record.snapshot``).

What it holds is the published messages' bytes as they came in the feed (msgpack, as a
subscriber receives them), never decoded objects: ``[flight_recorder] seconds`` + ``after_s`` +
``KEEP_MARGIN_S`` of them, about 0.2 MB a second on the built-in 2-joint rig (7 MB for the
default 30 s; while a storm's file is due, from its start on: up to
:data:`daemon.wire.flight.MAX_SPAN_S` more), and never more than ``MEMORY_CAP_BYTES`` whatever
the rig (then fewer seconds, which the file's first sample shows). A file is written once its
window's end has come in the feed (``after_s`` past its last event), or ``GRACE_S`` later by the
recorder's own clock if the feed has stopped (a stalled loop publishes nothing); it is written
in slices of ``slice_s`` between the recorder's other work (decoding and encoding 33 s of
telemetry takes seconds), so requests are answered meanwhile. A file begins no earlier than
where the previous trip's file ended (no second is written twice), and at most
``MAX_FILES_PER_HOUR`` are written in an hour: a storm of trips writes bounded files; a trip
past the cap is a ``record`` event (``failed``) instead.
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import msgpack

from daemon.recordings.mcap_log import McapRecording
from daemon.recordings.mcap_repair import repair
from daemon.wire.flight import Window
from hal.rig_sections import FlightRecorderConfig

KEEP_MARGIN_S = 1.0  # [s] held beyond seconds + after_s: the feed's batches and a file's end
MEMORY_CAP_BYTES = 64 * 1024 * 1024  # the held messages' bytes at most, whatever the rig
GRACE_S = 1.0  # [s] on the recorder's clock past a window's end: written with what came, if the feed stopped
MAX_FILES_PER_HOUR = 12
SLICE_S = 0.02  # [s] of writing at a time between the recorder's other work


@dataclass
class Flight:
    """A flight file due: its window on the daemon's clock, the events it is for."""

    name: str
    window: Window
    from_t: float  # [s] the daemon's clock: its first message
    due: float  # [s] the recorder's clock: written by then, whatever the feed
    who: str = ""
    events: list[dict] = field(default_factory=list)  # (kind, cycle, t, cause) of each
    items: list | None = None  # while written: the held messages it takes, and how far
    done: int = 0
    writer: McapRecording | None = None
    file: object = None
    path: str = ""


class FlightRecorder:
    def __init__(self, settings: FlightRecorderConfig, open_file: Callable[[str], tuple[object, str]],
                 close_file: Callable[[str], None], metadata: Callable[[], tuple[dict, dict]],
                 emit: Callable[[dict], None], clock: Callable[[], float] = time.monotonic):
        """``open_file(name)``: a new file (its name made unique), and its path;
        ``close_file(path)``: it is whole; ``metadata()``: describe and the controller now."""
        self.seconds, self.after_s = settings.seconds, settings.after_s
        self.keep_s = self.seconds + self.after_s + KEEP_MARGIN_S
        self._open, self._close, self._metadata, self.emit, self.clock = open_file, close_file, metadata, emit, clock
        self.held: deque[tuple[float, str, bytes]] = deque()  # (the daemon's clock when it came, topic, payload)
        self.bytes = 0
        self.due: list[Flight] = []  # oldest first; the first is the one being written
        self._written_to_t = float("-inf")  # [s] where the last trip's file ended: the next begins no earlier
        self._written: deque[float] = deque()  # the recorder's clock at each file begun in the last hour

    # -- the feed --------------------------------------------------------------------------
    def take(self, topic: str, body: bytes, feed_t: float | None) -> None:
        """One published message, kept as its bytes under the daemon's clock of the last state
        sample; those older than ``keep_s`` (or past the memory cap) go."""
        t = feed_t if feed_t is not None else 0.0
        held = self.held
        held.append((t, topic, body))
        self.bytes += len(body)
        horizon = t - self.keep_s
        if self.due and self.due[0].items is None:  # a file not begun yet keeps its start (a storm's)
            horizon = min(horizon, self.due[0].from_t)
        while held and (held[0][0] < horizon or self.bytes > MEMORY_CAP_BYTES):
            self.bytes -= len(held.popleft()[2])

    def event(self, event: dict) -> None:
        """An event in the feed: one the messenger named a flight file for opens it, or joins it."""
        name = event.get("flight")
        if not name:
            return
        t = float(event.get("t", 0.0))
        summary = {k: event.get(k) for k in ("kind", "cycle", "t", "cause")}
        for flight in self.due:
            if flight.name == name:
                flight.window.extend(t, self.after_s)
                flight.due = max(flight.due, self.clock() + flight.window.end_t - t + GRACE_S)
                self._written_to_t = max(self._written_to_t, flight.window.end_t)
                flight.events.append(summary)
                return
        now = self.clock()
        while self._written and now - self._written[0] > 3600.0:
            self._written.popleft()
        if len(self._written) >= MAX_FILES_PER_HOUR:
            self.emit({"kind": "record", "action": "failed", "name": name,
                       "cause": f"flight recorder: {MAX_FILES_PER_HOUR} files in the last hour already; this "
                                f"{event.get('kind')} is in the event topic and the journal only"})
            return
        self._written.append(now)
        self.due.append(Flight(name, Window(t, t + self.after_s), max(t - self.seconds, self._written_to_t),
                               now + self.after_s + GRACE_S, str(event.get("who", "")), [summary]))
        self._written_to_t = t + self.after_s

    def snapshot(self, name: str, who: str, feed_t: float | None) -> dict:
        """``record.snapshot``: the held seconds up to now, written as a flight file."""
        to_t = feed_t if feed_t is not None else 0.0
        flight = Flight(name, Window(to_t, to_t), to_t - self.seconds, self.clock(), who,
                        [{"kind": "snapshot", "cycle": None, "t": to_t, "cause": f"record.snapshot from {who}"}])
        self.due.append(flight)
        return {"name": name, "from_t": flight.from_t, "to_t": to_t, "seconds": self.seconds}

    def summary(self) -> dict:
        """For ``record.list``: what is held, and the flight files not yet written."""
        span = self.held[-1][0] - self.held[0][0] if self.held else 0.0
        return {"seconds": self.seconds, "after_s": self.after_s, "held_s": span, "held_bytes": self.bytes,
                "due": [f.name for f in self.due]}

    # -- writing ---------------------------------------------------------------------------
    def work(self, feed_t: float | None, slice_s: float = SLICE_S) -> bool:
        """Write the first due file for ``slice_s`` at most, once its window has ended (in the
        feed, or by the recorder's clock); True if work is left for now."""
        if not self.due:
            return False
        flight = self.due[0]
        if flight.items is None:
            ended = feed_t is not None and feed_t >= flight.window.end_t
            if not ended and self.clock() < flight.due:
                return False
            if not self._begin(flight):
                self.due.pop(0)
                return bool(self.due)
        ends = self.clock() + slice_s
        try:
            while flight.done < len(flight.items):
                _, topic, body = flight.items[flight.done]
                flight.done += 1
                flight.writer.write(topic, msgpack.unpackb(body, raw=False))
                if self.clock() > ends:
                    return True
            flight.writer.finish()
        except (OSError, ValueError) as exc:
            self._failed(flight, f"write error: {getattr(exc, 'strerror', None) or exc}")
        else:
            self._finished(flight)
        self.due.pop(0)
        return bool(self.due)

    def close(self) -> None:
        """The daemon stops: every due file written now, with what is held."""
        while self.due:
            self.due[0].due = float("-inf")
            self.work(None, float("inf"))

    def _begin(self, flight: Flight) -> bool:
        to_t = flight.window.end_t
        flight.items = [m for m in self.held if flight.from_t <= m[0] <= to_t]
        describe, controller = self._metadata()
        try:
            flight.file, flight.path = self._open(flight.name)
            flight.name = flight.path.rsplit("/", 1)[-1][:-len(".mcap")]
            first_t = flight.events[0]["t"]
            flight.writer = McapRecording(flight.file, describe, controller, plan={
                "planned_s": to_t - flight.from_t, "planned_end_t": to_t, "flight_from_t": flight.from_t,
                "flight_event_t": first_t})
        except (OSError, ValueError) as exc:
            self._failed(flight, f"cannot write it: {getattr(exc, 'strerror', None) or exc}")
            return False
        return True

    def _finished(self, flight: Flight) -> None:
        size = flight.file.tell()
        flight.file.close()
        self._close(flight.path)
        items = flight.items
        held_from = items[0][0] if items else None
        self.emit({"kind": "record", "action": "flight", "name": flight.name, "file": flight.path, "who": flight.who,
                   "from_t": flight.from_t, "to_t": flight.window.end_t, "held_from_t": held_from,
                   "seconds": (items[-1][0] - held_from) if items else 0.0, "messages": flight.writer.messages,
                   "gaps": flight.writer.gaps, "bytes": size, "events": flight.events,
                   "cause": "; ".join(f"{e['kind']}: {e['cause']}" for e in flight.events[:3])
                   + (f" and {len(flight.events) - 3} more" if len(flight.events) > 3 else "")})

    def _failed(self, flight: Flight, cause: str) -> None:
        """A file that could not be written: finished up to its last complete chunk, if begun."""
        if flight.file is not None:
            try:
                flight.file.close()
                repair(flight.path, cause)
            except (OSError, ValueError):
                pass
            self._close(flight.path)
        self.emit({"kind": "record", "action": "failed", "name": flight.name, "file": flight.path,
                   "cause": f"flight recorder: {cause}"})
