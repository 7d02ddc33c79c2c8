"""The daemon's journal, in the messenger: every event it publishes (the loop's, its own, the
recorder's) is one line of the daemon's log (this process's stderr: under systemd, the
journal), saying what happened, why, at which cycle and who asked. Written here, beside the
loop, as the event goes out: the loop never logs from its cycle.

A storm (a script that trips and resets in a loop, a flood of e-stops or one-shot commands)
costs a bounded number of lines: a token bucket of ``BURST`` lines, refilled at ``RATE_PER_S``
a second. What it holds back is counted by kind and said in one line once lines may be written
again; the ``event`` topic (and every recording) still has each one.

A line reads ``KIND: WHAT (WHY) [cycle N, WHO]``, e.g.
``trip: lease lost: the controlling client (alice) stopped renewing it; flight recording
flight-20261207-013000-trip-c51234.mcap [cycle 51234]``: a trip, an e-stop and a stalled loop
name the flight recorder's file of the seconds before them (:mod:`daemon.wire.flight`).
"""
from __future__ import annotations

import logging
import math
import time
from collections import Counter

BURST = 20  # lines written at once before the rate limit holds lines back
RATE_PER_S = 5.0  # lines a second after a burst
HELPER_DEATHS = ("messenger", "recorder", "planner", "contact", "exchange")  # (and the model's: a model event)  # a process beside the loop restarted
# Logged where they happen instead (start-up, shutdown: never in a cycle), or said by another
# event's line: a state change to fault or estop is its trip's or e-stop's line.
SAID_ELSEWHERE = ("plugin", "shutdown")
ERRORS = ("trip", "watchdog", *HELPER_DEATHS)  # watchdog: it wrote the safe state for a loop that could not
WARNINGS = ("estop", "unleased", "lease_revoked", "loop_stalled", "tracking", "model")  # model: the arm left its model
_SUBJECTS = ("name", "controller", "joint", "holder", "key")  # what an action is about, the first one present


class Journal:
    """Events to log lines, rate-limited."""

    def __init__(self, log: logging.Logger | None = None, clock=time.monotonic, burst: int = BURST,
                 rate_per_s: float = RATE_PER_S):
        self.log = log or logging.getLogger("pneumad")
        self.clock, self.burst, self.rate_per_s = clock, burst, rate_per_s
        self._tokens, self._filled = float(burst), clock()
        self._held: Counter[str] = Counter()  # kind -> events held back since the last line saying so
        self._held_since = 0.0

    def write(self, event: dict) -> None:
        """One line for ``event``, unless the rate limit holds it back (then counted)."""
        kind = str(event.get("kind"))
        if kind in SAID_ELSEWHERE or kind == "state" and event.get("to") in ("fault", "estop"):
            return
        if not self._take():
            if not self._held:
                self._held_since = self._filled
            self._held[kind] += 1
            return
        try:
            text = line(event)
        except Exception as exc:  # an event this module cannot read: said as it is, never fatal
            text = f"{kind}: {event!r:.300} (unreadable here: {type(exc).__name__}: {exc})"
        self.log.log(level(event), "%s", text)

    def flush(self) -> None:
        """Say what was held back, once a line may be written (called every half second)."""
        if self._held and self._refill() >= 1.0:
            self._say_held()

    def _take(self) -> bool:
        """A line may be written now (one token taken); what was held back is said first."""
        if self._refill() < 1.0:
            return False
        if self._held:
            self._say_held()
            if self._tokens < 1.0:
                return False
        self._tokens -= 1.0
        return True

    def _refill(self) -> float:
        now = self.clock()
        self._tokens = min(self.burst, self._tokens + (now - self._filled) * self.rate_per_s)
        self._filled = now
        return self._tokens

    def _say_held(self) -> None:
        held, self._held = self._held, Counter()
        self._tokens -= 1.0
        kinds = ", ".join(f"{kind} {n}" for kind, n in held.most_common())
        self.log.warning("journal: %d more events not written in the last %.1f s (%s): more than %d lines at once or "
                         "%g a second; the event topic and the daemon's recordings hold them all",
                         sum(held.values()), self.clock() - self._held_since, kinds, self.burst, self.rate_per_s)


def level(event: dict) -> int:
    """ERROR for a trip and a helper's death, WARNING for what stops or degrades the arm's work,
    INFO for the rest."""
    kind, action = event.get("kind"), event.get("action")
    if kind in ERRORS:
        return logging.ERROR
    if kind in WARNINGS or kind == "timing" and event.get("degraded") or kind == "lease" and action == "expire" \
            or kind == "record" and action in ("failed", "repaired") or kind == "experiment" and action == "abort" \
            or kind == "reload" and action == "refused":
        return logging.WARNING
    return logging.INFO


def line(event: dict) -> str:
    """``KIND: WHAT (WHY) [cycle N, WHO]``."""
    kind, cause = event.get("kind"), event.get("cause") or ""
    if kind in ("state", "controller"):
        what = f"{event.get('from')} -> {event.get('to')}"
    elif kind == "params":
        what = f"{event.get('controller')}'s parameters set: {', '.join(sorted(event.get('params') or {}))}"
    elif kind == "timing":
        action = event.get("action")
        what = ("degraded" if event.get("degraded") else "recovered") + (
            f", {action}" if action in ("hold", "trip") else "")
    elif kind == "loop_resumed":
        what = f"the loop cycles again after {event.get('stalled_s', math.nan):.2f} s"
    elif kind == "reload" and event.get("sha256"):
        what = f"{event.get('action')} {event.get('name')}: {event.get('file')} sha256 {str(event['sha256'])[:12]}"
    elif kind == "load" and event.get("action") == "set":
        what = f"set: {event.get('mass_kg')} kg at {event.get('com_mm')} mm"
    else:
        subject = next((str(event[k]) for k in _SUBJECTS if event.get(k) not in (None, "")), "")
        what = " ".join(str(p) for p in (event.get("action"), subject) if p)
    why = cause or event.get("cut") or ""
    text = f"{what} ({why})" if what and why else what or why
    if event.get("flight"):  # the flight recorder's file of its last seconds (daemon.wire.flight)
        text += f"; flight recording {event['flight']}.mcap"
    where = f"cycle {event.get('cycle')}" + (f", {event['who']}" if event.get("who") else "")
    return f"{kind}: {text} [{where}]"
