"""The flight recorder's files, as the messenger and the recorder both know them.

A trip, an e-stop or a stalled loop (:data:`TRIGGERS`) gets, in the messenger, as the event goes
out, a ``flight`` field naming the file that will hold it (:class:`FlightNames`): its journal line
and the event itself say where to look, and the loop waits for nothing. The recorder process
(:mod:`daemon.recorder.flight`) reads the field off the event in its feed and writes that file,
from ``[flight_recorder] seconds`` before its first event to the end of its :class:`Window`.

Events close together share a file: one that comes within the open file's window (``after_s``
past the event that opened it, pushed on by each later one, up to ``MAX_SPAN_S`` past the
first) is named with it, so a storm of trips writes one file while it lasts, not one each.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

TRIGGERS = ("trip", "estop", "loop_stalled")  # the events a flight file is written for
PREFIX = "flight-"
MAX_SPAN_S = 60.0  # [s] after its first event at most, a file's end is pushed on by later ones


def file_name(event: dict, wall: float | None = None) -> str:
    """``flight-YYYYmmdd-HHMMSS-KIND-cCYCLE``: when (this host's local time), what, at which cycle."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if wall is None else wall))
    return f"{PREFIX}{stamp}-{event.get('kind')}-c{event.get('cycle', 0)}"


@dataclass
class Window:
    """The span a flight file's later events fall in, on the daemon's clock [s]: from its first
    event to ``after_s`` past the last (at most ``MAX_SPAN_S`` past the first)."""

    first_t: float
    end_t: float

    def covers(self, t: float) -> bool:
        return self.first_t <= t <= self.end_t

    def extend(self, t: float, after_s: float) -> None:
        self.end_t = max(self.end_t, min(t + after_s, self.first_t + MAX_SPAN_S))


class FlightNames:
    """The messenger's side: names each triggering event's flight file, one name for events
    close together."""

    def __init__(self, after_s: float):
        self.after_s = after_s
        self.name: str | None = None  # the open file's
        self.window: Window | None = None

    def name_for(self, event: dict) -> str | None:
        """The flight file holding ``event``, or None if it asks for none (not a trigger)."""
        if event.get("kind") not in TRIGGERS:
            return None
        t = float(event.get("t", 0.0))
        if self.window is not None and self.window.covers(t):
            self.window.extend(t, self.after_s)
            return self.name
        self.name, self.window = file_name(event), Window(t, t + self.after_s)
        return self.name
