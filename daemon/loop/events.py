"""The loop's one event log: every part of the loop (supervisor, cycle, lease, port, an
experiment, a command) adds its events here, those a request causes are signed with who sent
it, and the cycle drains them to telemetry. A common cycle adds none, so the drain is one
test of an empty list."""
from __future__ import annotations


class EventLog:
    def __init__(self):
        self.pending: list[dict] = []  # added since the last drain, oldest first
        self._who: str | None = None  # who sent the request being handled (signs its events)

    def add(self, event: dict) -> None:
        """Append ``event``; while a request is handled it records who sent it (``who``),
        unless it already names someone."""
        if self._who is not None:
            event.setdefault("who", self._who)
        self.pending.append(event)

    def signed(self, who: str) -> "_Signed":
        """Sign with ``who`` every event added inside this ``with`` block (one request's
        handling). A plain context object, not a generator: it runs for every request."""
        return _Signed(self, who)

    def drain(self, publish) -> None:
        """Hand each pending event to ``publish`` (or drop them, given None), oldest first."""
        events = self.pending
        if publish is not None:
            for event in events:
                publish(event)
        events.clear()


class _Signed:
    __slots__ = ("log", "who", "outer")

    def __init__(self, log: EventLog, who: str):
        self.log, self.who, self.outer = log, who, None

    def __enter__(self) -> None:
        self.outer, self.log._who = self.log._who, self.who

    def __exit__(self, *exc) -> None:
        self.log._who = self.outer
