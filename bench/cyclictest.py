"""Run rt-tests' cyclictest beside a bench and read its histogram into percentiles."""
from __future__ import annotations

import shutil
import subprocess


def start(seconds: float, priority: int) -> subprocess.Popen | None:
    """cyclictest at ``priority`` with a 1 ms interval; None where it is not installed."""
    if shutil.which("cyclictest") is None:
        return None
    return subprocess.Popen(["cyclictest", "-m", "-p", str(priority), "-i", "1000", "-D", f"{int(seconds)}s",
                             "-q", "-h", "20000"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def result(proc: subprocess.Popen) -> dict[str, float]:
    """p50/p99/p99.9/max [us] from the histogram (one line per us: ``us count``)."""
    out, _ = proc.communicate()
    counts, worst = {}, None
    for line in out.splitlines():
        if line.startswith("# Max Latencies:"):
            worst = max(int(x) for x in line.split(":")[1].split())
        elif line[:1].isdigit():
            fields = line.split()
            counts[int(fields[0])] = sum(int(c) for c in fields[1:])
    total = sum(counts.values())
    out_p = {}
    for p in (50.0, 99.0, 99.9):
        target, running = p / 100.0 * total, 0
        for us in sorted(counts):
            running += counts[us]
            if running >= target:
                out_p[f"p{p:g}"] = float(us + 1)  # upper edge of the 1 us bin, as the loop reports
                break
    out_p["max"] = float(worst if worst is not None else max(counts))
    out_p["samples"] = total
    return out_p
