"""Work done off the loop: building a controller or deriving its parameters (a Riccati solve,
a c2d) takes milliseconds, several cycles, so it runs in one worker thread and the loop only
swaps the result in at a cycle boundary.

The worker is started when the daemon is built, before the real-time set-up, so it keeps the
normal scheduling policy and the loop's SCHED_FIFO thread preempts it. The GIL it holds is
mostly handed back within the interpreter's switch interval, which the daemon shortens
(``pneumad --gil-switch-us``), but not always: docs/benchmarks.md measures about one overrun
per build, which is why building belongs in a separate process (not done yet). One job at
a time: a second request while one is prepared is refused, so a flood of expensive requests
cannot queue up work.
"""
from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass


@dataclass
class Deferred:
    """A command whose reply waits for work off the loop. ``finish(result)`` runs on the loop
    thread once the work is done, applies it at that cycle boundary and returns the reply."""

    future: Future
    finish: Callable[[object], dict]
    request_id: object = None  # of the request it answers, set by the command layer


class Preparer:
    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pneumad-prepare")
        self._pool.submit(lambda: None).result()  # start the thread now, before any RT set-up
        self._current: Future | None = None

    @property
    def busy(self) -> bool:
        return self._current is not None and not self._current.done()

    def submit(self, work: Callable[[], object], finish: Callable[[object], dict]) -> Deferred:
        """Start ``work()`` in the worker; the caller checks :attr:`busy` first."""
        self._current = self._pool.submit(work)
        return Deferred(self._current, finish)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
