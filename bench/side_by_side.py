"""The loop's compute time, this checkout against an earlier commit, in alternating runs.

Usage: python -m bench.side_by_side [--base af6f830] [--rounds 6] [--seconds 20] [--subscribers 10]
                                    [--loop-cpu 1]

A cycle's cost on a shared machine drifts by half from one minute to the next (the host's
load, not the code), so a figure means something only beside the other tree's taken at the
same time. Each round runs ``bench.loop_latency`` once in a copy of ``--base`` and once in
this checkout, one straight after the other (same interpreter, same options); the table gives
each run's compute p50 / p99 (read + control + write + telemetry, as ``stats`` counts it)
and the round's p99 ratio, then, for p99 and p50, the pooled ratio (sum of this tree's
figures over the base's) and the median of the rounds' ratios.

The base is exported with ``git archive`` into a temporary directory and byte-compiled (the
daemon's helpers run with -B), so the checkout, its index and its worktrees are left as
they were. Its bench must print the ``compute compute`` row, as every commit since the
issue-30 baseline af6f830 does.
"""
from __future__ import annotations

import argparse
import compileall
import io
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from bench.common import header

CHECKOUT = Path(__file__).resolve().parent.parent
_ROW = re.compile(r"^compute (\w+)\s+us\s*: p50\s+([\d.]+)\s+p99\s+([\d.]+)", re.MULTILINE)
_OVERRUNS = re.compile(r"overruns (\d+)")


@dataclass
class Run:
    """One bench run's figures [us]: each stage's (p50, p99), and the overruns counted (-1:
    the output named none)."""

    stages: dict[str, tuple[float, float]]
    overruns: int

    @property
    def compute(self) -> tuple[float, float]:
        return self.stages["compute"]


def parse(output: str) -> Run:
    """The figures ``bench.loop_latency`` printed; ValueError naming what is missing."""
    stages = {name: (float(p50), float(p99)) for name, p50, p99 in _ROW.findall(output)}
    if "compute" not in stages:
        raise ValueError("no 'compute compute' row in the bench's output:\n" + output[-2000:])
    overruns = _OVERRUNS.search(output)
    return Run(stages, int(overruns.group(1)) if overruns else -1)


def ratios(pairs: list[tuple[Run, Run]], column: int = 1) -> tuple[float, float]:
    """(pooled, median) of this tree's compute p99 (``column`` 1; 0: p50) over the base's, for
    (base, this) pairs."""
    pooled = sum(new.compute[column] for _, new in pairs) / sum(base.compute[column] for base, _ in pairs)
    return pooled, statistics.median(new.compute[column] / base.compute[column] for base, new in pairs)


def export(commit: str, into: Path) -> Path:
    """``commit``'s tree in ``into``, byte-compiled; the checkout is only read."""
    archive = subprocess.run(["git", "-C", str(CHECKOUT), "archive", commit], capture_output=True)
    if archive.returncode != 0:
        raise SystemExit(f"cannot export {commit!r} from {CHECKOUT}: {archive.stderr.decode().strip()}")
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(into, filter="data")
    compileall.compile_dir(into, quiet=1)
    return into


def run_bench(tree: Path, options: list[str], seconds: float) -> Run:
    """``bench.loop_latency``'s figures, run in ``tree`` (its own modules first on the path) for
    ``seconds`` of load; given two minutes beyond that to start and stop its daemon."""
    proc = subprocess.run([sys.executable, "-m", "bench.loop_latency", *options], cwd=tree, capture_output=True,
                          text=True, timeout=seconds + 120)
    output = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise RuntimeError(f"bench.loop_latency in {tree} exited {proc.returncode}:\n{output[-2000:]}")
    return parse(output)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", default="af6f830", help="the commit to compare against (issue 30's baseline)")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--subscribers", type=int, default=10)
    ap.add_argument("--loop-cpu", type=int, default=1, help="the loop alone on this CPU (-1: anywhere)")
    args = ap.parse_args()
    options = ["--seconds", f"{args.seconds:g}", "--subscribers", str(args.subscribers)]
    if args.loop_cpu >= 0:
        options += ["--loop-cpu", str(args.loop_cpu)]
    here = subprocess.run(["git", "-C", str(CHECKOUT), "describe", "--always", "--dirty"], capture_output=True,
                          text=True).stdout.strip() or "this checkout"
    header(f"compute per cycle, {here} against {args.base}, alternating: bench.loop_latency {' '.join(options)}")
    pairs = []
    with tempfile.TemporaryDirectory(prefix="pneumad-base-") as directory:
        base = export(args.base, Path(directory))
        print(f"{'round, time':14s} {'load':>5s}  {'base p50/p99':>13s}  {'this p50/p99':>13s}  {'p99 ratio':>9s}  "
              f"{'overruns':>9s}")
        for k in range(1, args.rounds + 1):
            load = Path("/proc/loadavg").read_text().split()[0]
            started = time.strftime("%H:%M:%S")
            old = run_bench(base, options, args.seconds)
            new = run_bench(CHECKOUT, options, args.seconds)
            pairs.append((old, new))
            print(f"{k:2d}, {started:10s} {load:>5s}  {old.compute[0]:5.0f} / {old.compute[1]:5.0f}  "
                  f"{new.compute[0]:5.0f} / {new.compute[1]:5.0f}  {new.compute[1] / old.compute[1]:9.2f}  "
                  f"{old.overruns:4d} {new.overruns:4d}", flush=True)
    for name, column in (("p99", 1), ("p50", 0)):
        pooled, median = ratios(pairs, column)
        print(f"compute {name}, this over base: pooled {pooled:.2f}x, median of rounds {median:.2f}x "
              f"({len(pairs)} rounds)")
    for stage in ("read", "control", "write", "telemetry"):
        if all(stage in run.stages for pair in pairs for run in pair):
            old = statistics.median(b.stages[stage][0] for b, _ in pairs)
            new = statistics.median(n.stages[stage][0] for _, n in pairs)
            print(f"  {stage:9s} p50, median of runs: base {old:5.1f} us, this {new:5.1f} us")


if __name__ == "__main__":
    main()
