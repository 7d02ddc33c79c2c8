"""Clocks the loop runs on: the machine's monotonic clock, or a virtual one for lockstep tests.

Both offer ``now()`` [s] and ``sleep_until(t)``; the simulated transport takes ``now`` as its
time source, so on a :class:`VirtualClock` the plant advances exactly as the loop sleeps.
"""
from __future__ import annotations

import time


class MonotonicClock:
    """Real time: sleep to ``spin_s`` before the deadline, then spin (beats plain nanosleep jitter)."""

    def __init__(self, spin_s: float = 200e-6):
        self.spin_s = spin_s

    now = staticmethod(time.monotonic)

    def sleep_until(self, deadline: float) -> None:
        remaining = deadline - time.monotonic() - self.spin_s
        if remaining > 0:
            time.sleep(remaining)
        while time.monotonic() < deadline:
            pass


class VirtualClock:
    """Time moves only when the loop sleeps: deterministic and faster than real time."""

    def __init__(self, start: float = 0.0):
        self.t = start

    def now(self) -> float:
        return self.t

    def sleep_until(self, deadline: float) -> None:
        if deadline > self.t:
            self.t = deadline
