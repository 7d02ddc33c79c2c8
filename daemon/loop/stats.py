"""Loop timing statistics: wake-up latency and per-stage compute time, with fixed histograms.

Recording is O(1) and allocation-free per cycle (a bin increment and a max); percentiles
are read from the cumulative histogram once a window, and a window is cleared in place up to
its longest sample's bin: both cost what the window's samples span, not the 20 000 bins (a
fresh set of histograms cost the loop about 1 ms once a second).
"""
from __future__ import annotations

import math

BIN_US = 1.0  # histogram resolution [us]
BINS = 20000  # up to 20 ms; later samples land in the last bin (and in max)
# The parts of a cycle, then 'compute' (read + control + write + telemetry: the cycle's own
# work) and 'total' (compute + commands: how long the loop is busy each period).
STAGES = ("read", "control", "write", "telemetry", "commands", "compute", "total")
_BINS_PER_S = 1e6 / BIN_US
_ZEROS = [0] * BINS


class Histogram:
    def __init__(self):
        self.counts = [0] * BINS
        self.n = 0
        self.max_s = 0.0  # the longest sample [s]

    def clear(self) -> None:
        """Empty, touching only the bins a sample can have reached (those up to max_s)."""
        top = min(int(self.max_s * _BINS_PER_S) + 1, BINS)
        self.counts[:top] = _ZEROS[:top]
        self.counts[-1] = 0
        self.n = 0
        self.max_s = 0.0

    def add(self, seconds: float) -> None:
        i = int(seconds * _BINS_PER_S)
        self.counts[i if 0 <= i < BINS else (BINS - 1 if i >= BINS else 0)] += 1
        self.n += 1
        if seconds > self.max_s:
            self.max_s = seconds

    def percentiles(self, points=(50.0, 99.0, 99.9)) -> dict[str, float]:
        """Upper bin edges [us] at the given percentiles, and the maximum."""
        out = {}
        targets = [(p, math.ceil(p / 100.0 * self.n)) for p in points]
        running, k = 0, 0
        for i, c in enumerate(self.counts):
            running += c
            while k < len(targets) and running >= targets[k][1] and self.n:
                out[f"p{targets[k][0]:g}"] = (i + 1) * BIN_US
                k += 1
            if k == len(targets):
                break
        for p, _ in targets[k:]:
            out[f"p{p:g}"] = math.nan
        out["max"] = self.max_s * 1e6
        return out


class LoopStats:
    """Counters and histograms since the last reset (the 'stats' telemetry reads and resets a window)."""

    def __init__(self):
        self.latency = Histogram()
        self.stages = {name: Histogram() for name in STAGES}
        self._in_order = tuple(self.stages.values())
        self.overruns = 0
        self.cycles = 0
        self.overruns_total = 0
        self.cycles_total = 0

    def reset(self) -> None:
        self.latency.clear()
        for h in self._in_order:
            h.clear()
        self.overruns = 0
        self.cycles = 0

    def record_cycle(self, t0: float, t1: float, t2: float, t3: float, t4: float, t5: float) -> None:
        """One cycle's stage boundaries [s]: read t0-t1, control t1-t2, write t2-t3,
        telemetry t3-t4, commands t4-t5."""
        read, control, write, telemetry, commands, compute, total = self._in_order
        read.add(t1 - t0)
        control.add(t2 - t1)
        write.add(t3 - t2)
        telemetry.add(t4 - t3)
        commands.add(t5 - t4)
        compute.add(t4 - t0)
        total.add(t5 - t0)

    def summary(self, period: float) -> dict:
        return {
            "period_us": period * 1e6,
            "cycles": self.cycles,
            "cycles_total": self.cycles_total,
            "overruns": self.overruns,
            "overruns_total": self.overruns_total,
            "latency_us": self.latency.percentiles(),
            "compute_us": {name: h.percentiles() for name, h in self.stages.items()},
        }
