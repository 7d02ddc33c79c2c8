"""Loop timing statistics, the loop's side: wake-up latency and per-stage compute time counted
into fixed 1 us histograms in shared memory (:mod:`daemon.wire.loop_stats`).

Recording is O(1) and allocation-free per cycle (a bin increment and a max). Closing a window
is O(1) too: the loop switches bank and sends the window's counters; the percentiles are read,
and the bank cleared, beside the loop (:func:`daemon.wire.loop_stats.summarise`).
"""
from __future__ import annotations

from daemon.wire.loop_stats import BIN_US, BINS, STAGES, WINDOW, StatsBanks, percentiles

_BINS_PER_S = 1e6 / BIN_US
_LAST = BINS - 1


class Histogram:
    """One histogram of the bank the loop counts into: its counts, how many, the longest [s]."""

    def __init__(self, counts):
        self.counts = counts
        self.n = 0
        self.max_s = 0.0

    def add(self, seconds: float) -> None:
        i = int(seconds * _BINS_PER_S)
        self.counts[i if 0 <= i < BINS else (_LAST if i >= BINS else 0)] += 1
        self.n += 1
        if seconds > self.max_s:
            self.max_s = seconds

    def percentiles(self) -> dict[str, float]:
        """Upper bin edges [us] at p50, p99, p99.9, and the maximum: for a reader beside or
        after the loop (``pneumad latency``, tests), never in a cycle."""
        return percentiles(self.counts, self.n, self.max_s)


class LoopStats:
    """Counters and histograms of the window in progress, and of the loop's whole run."""

    def __init__(self, banks: StatsBanks | None = None):
        self.banks = banks if banks is not None else StatsBanks()
        self._bank = 0
        self.banks.take(0)
        self.latency, *stages = (Histogram(c) for c in self.banks.banks[0])
        self.stages = dict(zip(STAGES, stages))
        self._in_order = (self.latency, *stages)
        self.overruns = 0
        self.cycles = 0
        self.overruns_total = 0
        self.cycles_total = 0
        self.windows = 0  # closed so far: the stats topic's seq

    def record_cycle(self, t0: float, t1: float, t2: float, t3: float, t4: float, t5: float) -> None:
        """One cycle's stage boundaries [s]: read t0-t1, control t1-t2, write t2-t3,
        telemetry t3-t4, commands t4-t5."""
        _, read, control, write, telemetry, commands, compute, total = self._in_order
        read.add(t1 - t0)
        control.add(t2 - t1)
        write.add(t3 - t2)
        telemetry.add(t4 - t3)
        commands.add(t5 - t4)
        compute.add(t4 - t0)
        total.add(t5 - t0)

    def close_window(self, t: float, period: float) -> bytes | None:
        """End the window at ``t`` [s]: its message for :func:`~daemon.wire.loop_stats.summarise`,
        and a fresh window in the other bank; None (the window goes on) while the other bank has
        not been handed back yet."""
        other = 1 - self._bank
        if not self.banks.free(other):
            return None
        hs = self._in_order
        self.windows += 1
        message = WINDOW.pack(self.windows, self._bank, t, period, self.cycles, self.cycles_total, self.overruns,
                              self.overruns_total, *[v for h in hs for v in (h.n, h.max_s)])
        self.banks.take(other)
        for h, counts in zip(hs, self.banks.banks[other]):
            h.counts, h.n, h.max_s = counts, 0, 0.0
        self._bank = other
        self.overruns = 0
        self.cycles = 0
        return message

    @property
    def bank(self) -> int:
        """The bank the loop counts into now."""
        return self._bank

