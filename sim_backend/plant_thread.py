"""The simulated plant stepped beside the loop, as a DAQ's own processor samples its inputs.

In real time, the simulated transport's plant runs in a thread of the loop's process: it
steps the plant to the present on its own, takes the outputs the loop wrote, and leaves the
latest input sweep ready. A cycle's read then takes that sweep instead of computing the
physics in the cycle, as it takes the latest sample from a DAQ on a wire.

The thread ticks once a period, just after the loop's latest write (its phase follows the
writes): woken a little after the write, it takes the interpreter as the loop goes to sleep
at the end of its cycle, and is done long before the loop's next wake-up (timer-phased
ticks in the middle of the period missed the window about one period in thirty: a tick
delayed into the loop's spin before its deadline waits out the whole next cycle). So a
sample is most of a period old when the loop reads it, as from a DAQ that samples between
the loop's cycles. A tick follows each write, also one that comes late (the loop woken
late, or the thread's own tick held up): a tick held up past the next grid point used to
wait for the grid point after it, and the loop's next read found no new sweep.
Started from the loop's first read, the thread takes the loop's scheduling (SCHED_FIFO and
CPU placement are inherited), so the plant keeps pace with the loop it feeds.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

PHASE = 0.05  # a tick is due this fraction of a period after the loop's latest write
LATE_WRITE = 0.5  # a write up to this much of a period late is waited for; later, the plant ticks without it


class PlantThread:
    """Calls ``tick`` once every ``period_s``, phased on ``wrote_at()`` (when the loop last wrote
    [s, ``clock``'s time]): once after each write, and on the writes' grid while none comes (a
    stalled loop); a tick that raises ends the thread and is kept in :attr:`failure`."""

    def __init__(self, tick: Callable[[], None], period_s: float, clock: Callable[[], float],
                 wrote_at: Callable[[], float], sleep: Callable[[float], None] = time.sleep):
        self._tick, self._period, self._clock, self._wrote_at, self._sleep = tick, period_s, clock, wrote_at, sleep
        self._running = True
        self.failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="pneumad-sim-plant", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        h, clock, sleep = self._period, self._clock, self._sleep
        last, followed = clock(), None  # the last tick's end, and the write it came after
        try:
            while self._running:
                wrote = self._wrote_at()
                target = wrote + PHASE * h
                if wrote == followed:  # no write since the last tick: the writes' next grid point after it
                    target += h * max(1, int((last - target) / h) + 1)
                delay = target - clock()
                if delay > 0.0:
                    sleep(delay)
                while self._wrote_at() == followed and clock() < target + LATE_WRITE * h:
                    sleep(PHASE * h)  # the loop's write is late: the tick follows it, not the grid
                if not self._running:
                    break
                followed = self._wrote_at()
                self._tick()
                last = clock()
        except BaseException as exc:  # the loop's next read reports it: a transport failure, a trip
            self.failure = exc

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def close(self) -> None:
        self._running = False
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(1.0)
