"""What building controllers beside the loop costs it, now that the building is done in a
separate worker process (daemon/planner/process.py) and only its courier thread shares the GIL.

Usage: python -m bench.switch_load [--seconds 20] [--every 0.1] [--priority 80] [--cpus 1]

Runs a real ``pneumad`` (simulated rig, enabled, PID holding) three times: without switches,
then switching between smc and smc_dob every --every seconds (each build a Riccati solve, a
Kalman design and a c2d in the worker process) with the interpreter's default GIL switch
interval (5 ms, the daemon's default) and with a short one (``--gil-switch-us 100``). Prints the loop's
wake-up latency and compute time, overruns, and the switches done, per run.
"""
from __future__ import annotations

import argparse
import time

import msgpack

from bench.common import header, leased_daemon, percentiles


def run(seconds: float, every: float | None, gil_us: float, priority: int,
        cpus: str | None) -> tuple[dict | None, list[float]]:
    builds: list[float] = []
    with leased_daemon("--rt-priority", str(priority), "--gil-switch-us", str(gil_us), "--stats-period",
                       str(seconds), *(["--cpus", cpus] if cpus else []), timeout=5.0) as (client, stats_sub):
        client.enable()
        if stats_sub.poll(int((seconds + 5) * 1e3)):  # the first window holds the start-up: let it pass
            stats_sub.recv_multipart()
        start = time.monotonic()
        names = ["smc", "smc_dob"]
        while time.monotonic() - start < seconds - 0.5:
            if every is None:
                time.sleep(0.1)
                continue
            t0 = time.perf_counter()
            client.switch_controller(names[len(builds) % 2])
            builds.append(time.perf_counter() - t0)
            time.sleep(every)
        stats = msgpack.unpackb(stats_sub.recv_multipart()[1], raw=False) if stats_sub.poll(
            int((seconds + 5) * 1e3)) else None
    return stats, builds


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--every", type=float, default=0.1)
    ap.add_argument("--priority", type=int, default=80)
    ap.add_argument("--cpus", default=None, help="the loop's CPU affinity (pneumad --cpus)")
    args = ap.parse_args()
    header("loop figures while controllers are built beside it")
    print(f"{'run':38s} {'lat p50':>8s} {'p99':>7s} {'p99.9':>7s} {'max':>7s} {'comp p99':>9s} {'max':>7s} "
          f"{'overruns':>8s} {'switches':>8s} {'reply p50 ms':>12s}")
    for label, every, gil in (("no switches", None, 5000.0), ("switches, GIL interval 5000 us", args.every, 5000.0),
                              ("switches, GIL interval 100 us", args.every, 100.0)):
        stats, builds = run(args.seconds, every, gil, args.priority, args.cpus)
        if stats is None:
            print(f"{label:38s} no stats message")
            continue
        lat, comp = stats["latency_us"], stats["compute_us"]["total"]
        reply = f"{percentiles(builds)['p50'] * 1e3:12.1f}" if builds else f"{'-':>12s}"
        print(f"{label:38s} {lat['p50']:8.1f} {lat['p99']:7.1f} {lat['p99.9']:7.1f} {lat['max']:7.1f} "
              f"{comp['p99']:9.1f} {comp['max']:7.1f} {stats['overruns']:8d} {len(builds):8d} {reply}")


if __name__ == "__main__":
    main()
