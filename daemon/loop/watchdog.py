"""The cycle watchdog: a thread beside the loop's, in its process, that writes the safe state
through the transport when the loop cannot: a cycle (a controller's step, most often) that has
run longer than the rig file's ``[safety] stall_after_s``, a loop that has not woken by then, or
an e-stop the loop has not taken within ``ESTOP_GRACE_PERIODS`` periods of the messenger passing
it (the time the link carries, held against :attr:`ControlLoop.estop_taken_at`).

It costs the healthy loop a few attribute stores and loads a cycle (which controller is
stepping; :attr:`ControlLoop.in_io` around each transport call, made only while
:attr:`ControlLoop.held` is None), 0.1 us in all: no lock, two takes of which cost 0.8 us
(docs/benchmarks.md, "The cycle watchdog's cost"). The watchdog reads the loop's next deadline, which the loop keeps anyway,
and sleeps in one ``select`` on the e-stop FIFO (:mod:`daemon.wire.watchdog_link`) until that
deadline plus the stall limit. When it acts it sets ``held`` first, then waits for a transport
call of the loop's in progress to return (the GIL orders the stores, so by Dekker's rule
either the loop sees ``held`` and makes no call, or the watchdog sees ``in_io`` and waits),
and writes the safe state. While held the loop makes no transport call and does not write the
step's output; at its next cycle boundary it latches the e-stop or trips, puts the hold
controller in place of one whose step hung, and lets go (:meth:`ControlLoop.take_held`). The messenger publishes the ``watchdog`` event and its log
line from the link meanwhile (the loop's own events wait for it to cycle again), and answers
the e-stops it wrote as done: a loop merely late (a busy PC) has not stalled.

The GIL: ``time.sleep`` and blocking I/O release it, and a pure-Python busy loop lets the
watchdog in every ``sys.getswitchinterval()`` (``pneumad run --gil-switch-us``, 5 ms); a C
extension that holds it for ever cannot be helped in-process (docs/faults.md).
"""
from __future__ import annotations

import select
import threading
import time

from daemon.wire.watchdog_link import WatchdogLink
from hal.errors import TransportError

ESTOP_GRACE_PERIODS = 3  # an e-stop the loop has not taken within this many periods: written by the watchdog
ESTOP_GRACE_MIN_S = 0.002  # ... and at least this long [s]
LONGEST_SLEEP_S = 0.1  # it looks at least this often, so that stop() is prompt [s]
IO_POLL_S = 0.0002  # how often it looks whether the loop's transport call in progress has returned [s]


class CycleWatchdog:
    def __init__(self, loop, link: WatchdogLink):
        """Watch ``loop`` (a :class:`~daemon.loop.cycle.ControlLoop` on a monotonic clock) and
        hear e-stops through ``link``. Its times are ``time.monotonic``'s, as the other
        processes' it compares them with."""
        self.loop, self.link = loop, link
        self.limit_s = loop.rig.safety.stall_after_s
        self.estop_grace_s = max(ESTOP_GRACE_PERIODS * loop.period, ESTOP_GRACE_MIN_S)
        self.count = 0  # safe states written
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="cycle watchdog", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopped = True
        self._thread.join(timeout=2 * LONGEST_SLEEP_S + 1.0)

    def _run(self) -> None:
        loop, link, fd = self.loop, self.link, self.link.fd
        tripped_due = None  # the deadline it last tripped for: once per stall
        heard = False  # an e-stop's byte came, and the loop was not yet seen to take it
        while not self._stopped:
            now = time.monotonic()
            due = loop._deadline  # the cycle in progress's, or the next one's
            wake = due + self.limit_s if due != tripped_due else now + LONGEST_SLEEP_S
            if heard:
                wake = min(wake, link.estop_passed_at() + self.estop_grace_s)
            ready, _, _ = select.select((fd,), (), (), min(max(wake - now, 0.0), LONGEST_SLEEP_S))
            if self._stopped:
                return
            now = time.monotonic()
            if ready:
                link.drain()
                heard = True
            if heard:
                # the last e-stop passed against the last the loop took: the byte may be heard
                # after the loop took its e-stop (and was reset since), which must not latch again
                passed = link.estop_passed_at()
                if passed <= loop.estop_taken_at:
                    heard = False
                elif now - passed >= self.estop_grace_s:
                    self._write_safe("estop", self._estop_cause(now - passed, now - loop._deadline))
                    heard = False
            due = loop._deadline
            if due != tripped_due and now - due > self.limit_s:
                tripped_due = due
                self._write_safe("stall", self._stall_cause(now - due))

    def _estop_cause(self, waited_s: float, late_s: float) -> str:
        """An e-stop not taken in time, and where the loop was: a step running, or late (a PC
        busy with other work wakes it late), neither of which is a stall until ``limit_s``."""
        stepping = self.loop.stepping
        if stepping is not None:
            where = f"controller {stepping.name}'s step running"
        elif late_s > 0:
            where = f"the loop {late_s * 1e3:.1f} ms behind its deadline"
        else:
            where = "the loop waiting for its next cycle"
        return f"an e-stop the loop had not taken after {waited_s * 1e3:.0f} ms ({where})"

    def _stall_cause(self, late_s: float) -> str:
        stepping, limit = self.loop.stepping, self.limit_s
        what = f"controller {stepping.name}'s step has run" if stepping is not None else "the loop has been stuck"
        return (f"{what} for {late_s * 1e3:.0f} ms since the cycle was due (limit {limit * 1e3:.0f} ms: the rig "
                f"file's [safety] stall_after_s)")

    def _write_safe(self, kind: str, cause: str) -> None:
        """Hold the loop, wait for a transport call of its own in progress to end (Dekker's rule:
        :attr:`ControlLoop.in_io`), write the safe state, tell the messenger. Once per hold: while
        the loop is held it makes no transport call, and the outputs are already safe."""
        loop, held = self.loop, self.loop.held
        if held is not None:
            if kind == "stall":
                held.kind = "stall"  # a stall while an e-stop's hold waits for the loop: the stall is the reason
            return
        stepping = loop.stepping
        held = Held(kind, stepping.name if stepping is not None else None, self.limit_s)
        loop.held = held
        give_up = time.monotonic() + held.patience_s
        while loop.in_io and time.monotonic() < give_up:
            time.sleep(IO_POLL_S)
        written = False
        if loop.in_io:
            cause += (f": the cycle watchdog could not write the safe state (the loop's transport call has not returned "
                      f"in {held.patience_s * 1e3:.0f} ms)")
        else:
            try:
                loop.io.write_safe()
                written = True
                cause += ": the cycle watchdog wrote the safe state"
            except TransportError as exc:
                cause += f": the cycle watchdog could not write the safe state ({exc})"
        held.cause = cause
        held.done.set()
        self.count += 1
        self.link.wrote_safe(self.count, loop.cycle, time.monotonic(), cause, written)


class Held:
    """The watchdog's hold on the loop (:attr:`ControlLoop.held`): why (``kind``: ``stall`` or
    ``estop``; ``cause`` in words), the controller whose step was running (its name, or None),
    and ``done`` once its write is made."""

    def __init__(self, kind: str, stepping: str | None, patience_s: float):
        self.kind, self.stepping, self.cause = kind, stepping, ""
        self.patience_s = patience_s  # how long it waits for the loop's transport call [s]
        self.done = threading.Event()
