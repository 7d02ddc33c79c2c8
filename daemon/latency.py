"""Latency qualification: run the real loop on the simulated rig in real time and judge the PC.

Like LinuxCNC's latency test, it answers "can this PC close a 1 ms loop?" before anything is
trusted to it: a histogram of wake-up latency (how late each cycle started), percentiles,
compute time, overruns, and a verdict.
"""
from __future__ import annotations

import gc
import math

from daemon.assembly import loop_from_args, realtime_setup
from daemon.loop.clock import MonotonicClock
from daemon.service import realtime

# Verdict bounds, as fractions of the period.
GOOD_P999, GOOD_MAX = 0.10, 0.50  # p99.9 within 10 %, worst within 50 % of the period
USABLE_P999, USABLE_MAX = 0.25, 1.00


def verdict(latency: dict, overruns: int, period: float) -> str:
    p999, worst = latency["p99.9"] * 1e-6, latency["max"] * 1e-6
    if overruns == 0 and p999 <= GOOD_P999 * period and worst <= GOOD_MAX * period:
        return "GOOD: this PC holds the period with margin"
    if p999 <= USABLE_P999 * period and worst <= USABLE_MAX * period:
        return "USABLE: occasional late cycles; use SCHED_FIFO, an isolated CPU and a quiet machine"
    return "NOT SUITABLE: wake-ups too late for this period; fix the system (RT kernel, isolcpus) first"


def histogram_lines(counts: list[int], width: int = 40) -> list[str]:
    """Log2-binned text histogram of a 1 us histogram."""
    bins, edge, start = [], 1, 0
    while start < len(counts):
        end = min(edge * 2, len(counts))
        bins.append((start, end, sum(counts[start:end])))
        start, edge = end, edge * 2
    total = max(sum(c for _, _, c in bins), 1)
    lines = []
    for lo, hi, c in bins:
        if c:
            bar = "#" * max(1, int(width * math.log1p(c) / math.log1p(total)))
            lines.append(f"{lo:6d}-{hi:<6d} us {c:9d} {bar}")
    return lines


def qualify(args) -> int:
    clock = MonotonicClock(spin_s=args.spin_us * 1e-6)
    loop = loop_from_args(args, clock)
    for w in realtime_setup(args):
        print(f"warning: {w}")
    gc.collect()
    gc.freeze()
    gc.disable()
    loop.stats_period = math.inf  # keep the whole run in one window
    loop.start()
    loop.enable()
    cycles = int(args.seconds / args.period)
    loop.run(cycles)
    gc.enable()
    loop.shutdown("latency test done")
    stats = loop.stats
    lat = stats.latency.percentiles()
    comp = stats.stages["total"].percentiles()
    print(f"latency qualification: {cycles} cycles at {args.period * 1e3:.3f} ms, {realtime.describe()}")
    print("wake-up latency histogram:")
    for line in histogram_lines(stats.latency.counts):
        print("  " + line)
    print("wake-up latency  us: " + "  ".join(f"{k} {v:.0f}" for k, v in lat.items()))
    print("compute per cycle us: " + "  ".join(f"{k} {v:.0f}" for k, v in comp.items()))
    print(f"overruns: {stats.overruns}")
    print("verdict: " + verdict(lat, stats.overruns, args.period))
    return 0
