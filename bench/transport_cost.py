"""What each transport costs the loop, against the in-process simulator and the wire's floor.

    python -m bench.transport_cost [--seconds 10] [--priority 80]

For each transport a real ``pneumad`` runs (SCHED_FIFO, enabled, PID holding) against the
simulated rig: in process, or as a peer process behind the wire (SCHED_FIFO, 10 below the
loop). Printed from the daemon's
own ``stats`` telemetry (one window after start-up): wake-up latency, the read and write
stages of a cycle (the transport's per-cycle cost), overruns. The floor is the raw loopback
round trip of the same kind of wire with nothing but an echo on the other end: a pty for the
serial bridge, TCP for Modbus, UDP for CAN over udp_multicast.
"""
from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
import tty
from contextlib import contextmanager

import msgpack

from bench import wires
from bench.common import header, leased_daemon, percentiles
from daemon.client.client import RemoteError
from daemon.testing.ports import free_tcp_port
from hal import serial_frames as F


def transport_options(wire: wires.Wire, priority: int) -> list[str]:
    options = dict(wire.options)
    if wire.backend == "modbus":
        options["worker_priority"] = priority  # the exchange worker, like the peer, answers on time
    return ["--transport", wire.backend, *sum((["--transport-option", f"{k}={v}"] for k, v in options.items()), [])]


def run(wire: wires.Wire | None, seconds: float, priority: int) -> dict | str | None:
    """The daemon's second stats window; the peer runs at SCHED_FIFO just below the loop,
    as a microcontroller or an I/O module would answer: on time, whatever else the PC does."""
    peer = wires.start_peer(wire.peer, wire.ready, priority=priority - 10) if wire else None
    try:
        with leased_daemon("--rt-priority", str(priority), "--stats-period", str(seconds),
                           *(transport_options(wire, priority - 10) if wire else []), timeout=30.0) as (client, stats):
            try:
                client.enable()
            except RemoteError as exc:  # e.g. a wire too slow for the rig's stale limit
                return exc.message
            windows = []
            while len(windows) < 2 and stats.poll(int((seconds + 10) * 1e3)):
                windows.append(msgpack.unpackb(stats.recv_multipart()[1], raw=False))
            return windows[-1] if len(windows) == 2 else None
    finally:
        if peer is not None:
            wires.stop_peer(peer)


PTY_ECHO = "import os, sys\nfd = int(sys.argv[1])\nwhile True:\n    os.write(fd, os.read(fd, 4096))"
TCP_ECHO = ("import socket, sys\ns = socket.create_server(('127.0.0.1', int(sys.argv[1])))\nwhile True:\n"
            "    c, _ = s.accept()\n    c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)\n"
            "    while (d := c.recv(4096)):\n        c.sendall(d)")
UDP_ECHO = ("import socket, sys\ns = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n"
            "s.bind(('127.0.0.1', int(sys.argv[1])))\nwhile True:\n    d, a = s.recvfrom(4096)\n    s.sendto(d, a)")


def round_trips(send, receive, size: int, n: int = 5000) -> dict[str, float]:
    """Percentiles [us] of ``send`` then ``receive`` of ``size`` bytes, n times."""
    samples = []
    payload = bytes(range(size))
    for _ in range(n):
        t0 = time.perf_counter()
        send(payload)
        got = 0
        while got < size:
            got += len(receive())
        samples.append((time.perf_counter() - t0) * 1e6)
    return percentiles(samples)


@contextmanager
def echo(script: str, *args: str, pass_fds: tuple[int, ...] = ()):
    """An echo process for the duration of the block."""
    proc = subprocess.Popen([sys.executable, "-c", script, *args], pass_fds=pass_fds)
    try:
        yield proc
    finally:
        proc.kill()
        proc.wait()


def floors() -> dict[str, dict[str, float]]:
    """The raw loopback round trip of each wire, to an echo process, at the size of one exchange."""
    out = {}
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        with echo(PTY_ECHO, str(master), pass_fds=(master,)):
            out["pty (serial)"] = round_trips(lambda b: os.write(slave, b), lambda: os.read(slave, 4096),
                                              len(F.encode(F.OUTPUTS, 1, [0] * 4)))
    finally:
        os.close(slave)
        os.close(master)
    port = free_tcp_port()
    with echo(TCP_ECHO, str(port)):
        while not wires.listening(port):
            time.sleep(0.02)
        with socket.create_connection(("127.0.0.1", port)) as sock:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            out["tcp (modbus)"] = round_trips(sock.sendall, lambda: sock.recv(4096), 25)  # a function-23 request
    port = free_tcp_port()
    with echo(UDP_ECHO, str(port)), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        time.sleep(0.5)
        sock.connect(("127.0.0.1", port))
        out["udp (can)"] = round_trips(sock.send, lambda: sock.recv(4096), 16)  # one CAN frame's bytes
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--priority", type=int, default=80)
    args = ap.parse_args()
    header("the loop with each transport (simulated rig behind it)")
    print(f"{'transport':16s} {'lat p50':>8s} {'p99':>7s} {'p99.9':>7s} {'max':>8s}  {'read p50':>8s} {'p99':>7s}"
          f"  {'write p50':>9s} {'p99':>7s}  {'overruns':>8s}")
    with tempfile.TemporaryDirectory(prefix="pneumad-transport-") as tmp:
        for name, wire in {"in-process sim": None, **wires.wires(tmp)}.items():
            s = run(wire, args.seconds, args.priority)
            if not isinstance(s, dict):
                print(f"{name:16s} {s or 'no stats'}")
                continue
            lat, rd, wr = s["latency_us"], s["compute_us"]["read"], s["compute_us"]["write"]
            print(f"{name:16s} {lat['p50']:8.1f} {lat['p99']:7.1f} {lat['p99.9']:7.1f} {lat['max']:8.1f}  "
                  f"{rd['p50']:8.1f} {rd['p99']:7.1f}  {wr['p50']:9.1f} {wr['p99']:7.1f}  {s['overruns']:8d}")
    print()
    print("floor: raw loopback round trip of each wire to an echo process, one exchange's bytes, us")
    for name, rt in floors().items():
        print(f"{name:16s} p50 {rt['p50']:7.1f}  p99 {rt['p99']:7.1f}  p99.9 {rt['p99.9']:7.1f}  max {rt['max']:8.1f}")


if __name__ == "__main__":
    main()
