"""What each command costs the loop: every case of bench/command_cases.py (every command of
docs/protocol.md, accepted and refused, with its largest allowed arguments) sent in turn to a
real, real-time ``pneumad`` on the simulated rig, with the loop's own figures.

Usage: python -m bench.command_stall [--repeat 10] [--window 0.2] [--no-rt] [--cpus 1] [--only TEXT]

Per case ``--repeat`` rounds of: put the daemon in the state the case needs (unmeasured), send the
case's request and time its reply. The daemon publishes ``stats`` every ``--window`` s; the
windows that end while a case's requests are in flight are that case's: their worst compute
time (read + control + write + telemetry) and total time (with command handling), and their
overruns, and their worst wake-up latency (a late wake-up is the machine's: the VM stalls the
whole guest now and then). Then a quiet baseline (no requests) as long as all the cases
together: a spike it shows as well is the machine's, not a command's; the table gives both.
"""
from __future__ import annotations

import argparse
import time

import msgpack

from bench.command_cases import CASES, prepare, send
from bench.common import header, leased_daemon, percentiles
from daemon.client.client import RemoteError


def drain(stats_sub, until: float) -> list[dict]:
    """Every stats window published until ``until`` (monotonic time) and a moment after."""
    windows = []
    while stats_sub.poll(max(0, int((until - time.monotonic()) * 1e3)) + 50):
        windows.append(msgpack.unpackb(stats_sub.recv_multipart()[1], raw=False))
        if windows[-1]["t"] >= until:
            break
    return windows


GOAL_US = 250.0  # the loop's compute max while a command is handled (issue 12)


def figures(windows: list[dict]) -> tuple[float, float, float, int, int, float]:
    """Worst compute, total and wake-up latency [us], overruns, cycles, and the share of
    windows whose compute max is over GOAL_US, over the windows."""
    if not windows:
        return float("nan"), float("nan"), float("nan"), 0, 0, float("nan")
    over = sum(w["compute_us"]["compute"]["max"] > GOAL_US for w in windows) / len(windows)
    return (max(w["compute_us"]["compute"]["max"] for w in windows), max(w["compute_us"]["total"]["max"] for w in windows),
            max(w["latency_us"]["max"] for w in windows), sum(w["overruns"] for w in windows),
            sum(w["cycles"] for w in windows), over)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--window", type=float, default=0.2, help="stats window [s]")
    ap.add_argument("--no-rt", action="store_true")
    ap.add_argument("--cpus", default=None, help="the loop's CPU affinity (pneumad --cpus)")
    ap.add_argument("--only", default=None, metavar="TEXT", help="just the cases whose label contains TEXT")
    args = ap.parse_args()
    cases = [c for c in CASES if args.only is None or args.only in c.label]
    header("the loop while each command is handled")
    options = ["--stats-period", str(args.window), *(["--no-rt"] if args.no_rt else []),
               *(["--cpus", args.cpus] if args.cpus else [])]
    with leased_daemon(*options, timeout=10.0) as (client, stats_sub):
        client.enable()
        time.sleep(1.0)
        drain(stats_sub, time.monotonic())  # start-up windows
        rows, busy = [], 0.0
        for case in cases:
            replies, windows, codes = [], [], set()
            for _ in range(args.repeat):
                prepare(client, case)
                drain(stats_sub, time.monotonic())  # preparation's windows are not the case's
                t0 = time.monotonic()
                reply = send(client, case)
                replies.append(time.monotonic() - t0)
                codes.add(reply.code if isinstance(reply, RemoteError) else "ok")
                windows += drain(stats_sub, time.monotonic() + args.window)
            busy += sum(replies) + args.repeat * args.window
            rows.append((case, percentiles(replies), figures(windows), codes))
        client.abort()
        drain(stats_sub, time.monotonic())
        baseline = figures(drain(stats_sub, time.monotonic() + busy))
    print(f"| command | reply | reply p50 ms | p99 ms | compute max us | windows over {GOAL_US:.0f} us | "
          f"total max us | wake-up max us | overruns | cycles |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for case, reply, (compute, total, wake, overruns, cycles, over), codes in rows:
        print(f"| {case.label} | {', '.join(sorted(codes))} | {reply['p50'] * 1e3:.1f} | {reply['p99'] * 1e3:.1f} | "
              f"{compute:.0f} | {over:.0%} | {total:.0f} | {wake:.0f} | {overruns} | {cycles} |")
    print(f"| *quiet baseline, {busy:.0f} s* | | | | {baseline[0]:.0f} | {baseline[5]:.0%} | {baseline[1]:.0f} | "
          f"{baseline[2]:.0f} | {baseline[3]} | {baseline[4]} |")
    windows_over = sum(r[2][5] * r[2][4] for r in rows) / sum(r[2][4] for r in rows)
    print(f"\nwhile commands were handled: worst compute {max(r[2][0] for r in rows):.0f} us, windows over "
          f"{GOAL_US:.0f} us {windows_over:.1%} (quiet: {baseline[5]:.1%}), {sum(r[2][3] for r in rows)} overruns in "
          f"{sum(r[2][4] for r in rows)} cycles (quiet: {baseline[3]} in {baseline[4]})")


if __name__ == "__main__":
    main()
