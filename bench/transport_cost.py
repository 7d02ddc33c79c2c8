"""What each transport costs the loop, against the in-process simulator and the wire's floor.

    python -m bench.transport_cost [--seconds 10] [--priority 80]

For each transport a real ``pneumad`` runs (SCHED_FIFO, enabled, PID holding) against the
simulated rig: in process, or as a peer process behind the wire (SCHED_FIFO, 10 below the
loop). Printed from the daemon's
own ``stats`` telemetry (one window after start-up): wake-up latency, the read and write
stages of a cycle (the transport's per-cycle cost), overruns. The floor is the raw loopback
round trip of the same wire with nothing but an echo on the other end.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import tty

import msgpack

from bench.common import header, percentiles, spawn_daemon, stats_subscriber
from daemon.client import Client
from hal import serial_frames as F


def peers(tmp: str) -> dict[str, tuple[list[str] | None, list[str], str | None]]:
    """name -> (peer command, pneumad options, a path that exists once the peer is up)."""
    link = os.path.join(tmp, "bridge")
    return {
        "in-process sim": (None, [], None),
        "serial (pty)": ([sys.executable, "-m", "sim_backend.serial_peer", "--link", link],
                         ["--transport", "serial", "--transport-option", f"port={link}"], link),
    }


def run(peer_cmd, options, ready_path, seconds: float, priority: int) -> dict | None:
    """The daemon's second stats window; the peer runs at SCHED_FIFO just below the loop,
    as a microcontroller would answer: on time, whatever else the PC does."""
    peer = subprocess.Popen(peer_cmd, stdout=subprocess.DEVNULL, preexec_fn=lambda: _realtime(priority - 10)) \
        if peer_cmd else None
    try:
        while ready_path and not os.path.exists(ready_path):
            time.sleep(0.05)
        daemon, eps = spawn_daemon("--rt-priority", str(priority), "--stats-period", str(seconds), *options)
        try:
            client = Client(**eps, timeout=10.0)
            client.ping()
            stats = stats_subscriber(eps)
            client.acquire_lease()
            client.keep_lease()
            client.enable()
            windows = []
            while len(windows) < 2 and stats.poll(int((seconds + 10) * 1e3)):
                windows.append(msgpack.unpackb(stats.recv_multipart()[1], raw=False))
            client.close()
            return windows[-1] if len(windows) == 2 else None
        finally:
            daemon.terminate()
            daemon.wait(10)
    finally:
        if peer is not None:
            peer.terminate()
            peer.wait(10)


def _realtime(priority: int) -> None:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:
        pass  # not permitted: the peer runs at normal priority, and the figures say less


ECHO = "import os, sys\nfd = int(sys.argv[1])\nwhile True:\n    os.write(fd, os.read(fd, 4096))"


def pty_round_trip(n: int = 5000) -> dict[str, float]:
    """A bridge-sized frame through a pty pair to an echo process and back [us]."""
    master, slave = os.openpty()
    tty.setraw(slave)
    echo = subprocess.Popen([sys.executable, "-c", ECHO, str(master)], pass_fds=(master,))
    frame = F.encode(F.OUTPUTS, 1, [1000] * 4)
    samples = []
    try:
        for _ in range(n):
            t0 = time.perf_counter()
            os.write(slave, frame)
            got = b""
            while len(got) < len(frame):
                got += os.read(slave, 4096)
            samples.append((time.perf_counter() - t0) * 1e6)
    finally:
        echo.kill()
        echo.wait()
        os.close(slave)
        os.close(master)
    return percentiles(samples)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--priority", type=int, default=80)
    args = ap.parse_args()
    header("the loop with each transport (simulated rig behind it)")
    print(f"{'transport':16s} {'lat p50':>8s} {'p99':>7s} {'p99.9':>7s} {'max':>8s}  {'read p50':>8s} {'p99':>7s}"
          f"  {'write p50':>9s} {'p99':>7s}  {'overruns':>8s}")
    with tempfile.TemporaryDirectory(prefix="pneumad-transport-") as tmp:
        for name, (peer_cmd, options, ready) in peers(tmp).items():
            s = run(peer_cmd, options, ready, args.seconds, args.priority)
            if s is None:
                print(f"{name:16s} no stats")
                continue
            lat, rd, wr = s["latency_us"], s["compute_us"]["read"], s["compute_us"]["write"]
            print(f"{name:16s} {lat['p50']:8.1f} {lat['p99']:7.1f} {lat['p99.9']:7.1f} {lat['max']:8.1f}  "
                  f"{rd['p50']:8.1f} {rd['p99']:7.1f}  {wr['p50']:9.1f} {wr['p99']:7.1f}  {s['overruns']:8d}")
    print()
    print("floor: raw loopback round trip of each wire, a bridge-sized frame, us")
    rt = pty_round_trip()
    print(f"{'pty':16s} p50 {rt['p50']:.1f}  p99 {rt['p99']:.1f}  p99.9 {rt['p99.9']:.1f}  max {rt['max']:.1f}")


if __name__ == "__main__":
    main()
