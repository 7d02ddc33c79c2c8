"""The loop's timing histograms in shared memory, and their summary beside the loop.

The loop counts each cycle's wake-up latency and stage times into 1 us histograms (an
increment a sample, :mod:`daemon.loop.stats`). Reading percentiles from them and clearing
them costs what a window's samples span (about 120 us once a second), so that is not the
loop's work: the histograms live in two banks of shared memory. At the end of a stats window
the loop switches to the other bank and sends a small window message (the counters, each
histogram's count and maximum, which bank); the messenger (or, in-process, whoever takes
the loop's telemetry) turns it into the ``stats`` topic's message with :func:`summarise`,
which also clears the bank and hands it back. A bank not yet handed back when the next
window ends is not reused: the loop keeps counting into the one it has, and that window
simply runs longer (its ``cycles`` say so).
"""
from __future__ import annotations

import math
import mmap
import os
import struct

import numpy as np

BIN_US = 1.0  # histogram resolution [us]
BINS = 20000  # up to 20 ms; later samples land in the last bin (and in max)
# The parts of a cycle, then 'compute' (read + control + write + telemetry: the cycle's own
# work) and 'total' (compute + commands: how long the loop is busy each period).
STAGES = ("read", "control", "write", "telemetry", "commands", "compute", "total")
HISTOGRAMS = ("latency", *STAGES)
PERCENTILES = (50.0, 99.0, 99.9)
FILE_NAME = "loop-stats"

_COUNT = struct.calcsize("I")
_BANK_BYTES = len(HISTOGRAMS) * BINS * _COUNT
_HEADER = struct.Struct("<III")  # bank 0 free, bank 1 free (1: cleared and handed back), the bank in use
# the window message: seq, bank, t [s], period [s], cycles, cycles_total, overruns, overruns_total;
# then count and maximum [s] per histogram, in HISTOGRAMS' order
WINDOW = struct.Struct("<QBdd4Q" + "Qd" * len(HISTOGRAMS))
_SIZE = _HEADER.size + 2 * _BANK_BYTES


class StatsBanks:
    """Two banks of histograms in one shared map (a file in the rings' directory, or
    anonymous memory for a loop run in-process)."""

    def __init__(self, path: str | None = None, create: bool = True):
        if path is None:
            self._map = mmap.mmap(-1, _SIZE)
        else:
            fd = os.open(path, os.O_RDWR | (os.O_CREAT | os.O_TRUNC if create else 0), 0o600)
            try:
                if create:
                    os.ftruncate(fd, _SIZE)
                self._map = mmap.mmap(fd, _SIZE)
            finally:
                os.close(fd)
        if create:
            _HEADER.pack_into(self._map, 0, 0, 1, 0)  # the loop counts into bank 0; bank 1 is free
        whole = memoryview(self._map)
        self._flags = whole[:_HEADER.size].cast("I")
        self.banks = tuple(tuple(whole[_HEADER.size + (b * len(HISTOGRAMS) + h) * BINS * _COUNT:][:BINS * _COUNT]
                                 .cast("I") for h in range(len(HISTOGRAMS))) for b in range(2))
        self._array = np.frombuffer(self._map, dtype=np.uint32, count=2 * len(HISTOGRAMS) * BINS,
                                    offset=_HEADER.size).reshape(2, len(HISTOGRAMS), BINS)

    @classmethod
    def in_directory(cls, directory: str, create: bool) -> "StatsBanks":
        return cls(os.path.join(directory, FILE_NAME), create)

    def free(self, bank: int) -> bool:
        """Whether ``bank`` has been summarised, cleared and handed back."""
        return self._flags[bank] == 1

    def take(self, bank: int) -> None:
        """The loop counts into ``bank`` from now on."""
        self._flags[bank] = 0
        self._flags[2] = bank

    def counts(self, bank: int, histogram: int) -> np.ndarray:
        return self._array[bank, histogram]

    def release(self, bank: int, tops: list[int]) -> None:
        """Clear ``bank`` (each histogram up to its top bin, and its last bin) and hand it back."""
        for h, top in enumerate(tops):
            self._array[bank, h, :top] = 0
            self._array[bank, h, -1] = 0
        self._flags[bank] = 1

    def reclaim(self) -> None:
        """A messenger started again: the bank the loop is not counting into, whose window message
        may have been lost with the one before, is cleared and handed back."""
        other = 1 - self._flags[2]
        if not self.free(other):
            self._array[other] = 0
            self._flags[other] = 1


def percentiles(counts, n: int, max_s: float, points=PERCENTILES) -> dict[str, float]:
    """Upper bin edges [us] at the given percentiles of a histogram holding ``n`` samples, and
    its maximum [us]. Costs what the samples span (up to the maximum's bin), not 20 000 bins."""
    out = {}
    top = min(int(max_s * 1e6 / BIN_US) + 1, BINS)
    cumulative = np.cumsum(np.concatenate((np.asarray(counts[:top], dtype=np.int64), [counts[BINS - 1]]
                                           if top < BINS else [])))
    for p in points:
        target = math.ceil(p / 100.0 * n)
        if n == 0 or not len(cumulative) or cumulative[-1] < target:
            out[f"p{p:g}"] = math.nan
            continue
        i = int(np.searchsorted(cumulative, target))
        out[f"p{p:g}"] = ((i if i < top else BINS - 1) + 1) * BIN_US
    out["max"] = max_s * 1e6
    return out


def summarise(banks: StatsBanks, body: bytes, release: bool = True) -> dict:
    """The ``stats`` topic's message (docs/protocol.md) for a window message from the loop;
    the window's bank is cleared and handed back (unless ``release`` is False: a second reader,
    a test's, beside the messenger that does)."""
    seq, bank, t, period, cycles, cycles_total, overruns, overruns_total, *tail = WINDOW.unpack(body)
    found = {}
    tops = []
    for h, name in enumerate(HISTOGRAMS):
        n, max_s = tail[2 * h], tail[2 * h + 1]
        found[name] = percentiles(banks.counts(bank, h), n, max_s)
        tops.append(min(int(max_s * 1e6 / BIN_US) + 1, BINS))
    if release:
        banks.release(bank, tops)
    return {"period_us": period * 1e6, "cycles": cycles, "cycles_total": cycles_total, "overruns": overruns,
            "overruns_total": overruns_total, "latency_us": found["latency"],
            "compute_us": {name: found[name] for name in STAGES}, "t": t, "seq": seq}
