"""The daemon's loop under its full workload, against cyclictest run at the same time.

Usage: python -m bench.loop_latency [--seconds 30] [--subscribers 10] [--priority 80] [--loop-cpu N] [--keys]
                                    [--foxglove] [--snapshots S]

Starts a real ``pneumad`` (simulated rig, PID enabled, SCHED_FIFO at --priority where
permitted) and cyclictest at the same priority, then loads the daemon from this process:
--subscribers telemetry subscribers (one of them never reads), a client pinging at about
200 Hz (command round trip), reading status at 50 Hz and moving the set-point at 5 Hz
(set-point-to-effect, in cycles, from the telemetry). Prints the daemon's wake-up latency
and compute time over the whole run (one stats window), cyclictest's, and their ratios.

--loop-cpu N sets the machine up as a lab would (isolcpus): the loop alone on CPU N, and
everything else (the daemon's helper processes, this load generator, cyclictest) on the
other CPUs, so cyclictest then measures the CPUs that carry the load.

--keys runs the daemon with CURVE keys (every socket encrypted and authenticated, every
client of this bench holding an allowed key): the same figures, with CURVE's cost in them.

--foxglove runs the daemon with its live Foxglove stream (``--foxglove 127.0.0.1:PORT``) and
connects two Foxglove WebSocket clients subscribed to every channel, one reading everything,
one stalled: the same figures with the stream's cost in them, and the messenger's CPU time.

--snapshots S asks for a ``record.snapshot`` every S seconds: the flight recorder writing the
seconds it holds to a file beside the loop (docs/recordings.md, "The flight recorder"), as on
each trip, without the trip.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import threading
import time

import msgpack
import zmq

from bench import cyclictest
from bench.common import Trips, header, percentiles, secure, spawn_daemon, stats_subscriber, with_keys
from daemon.client.client import Client, RemoteError
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.ports import free_tcp_port


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--subscribers", type=int, default=10)
    ap.add_argument("--priority", type=int, default=80)
    ap.add_argument("--loop-cpu", type=int, default=None, help="the loop alone on this CPU, the rest elsewhere")
    ap.add_argument("--keys", action="store_true", help="CURVE on every socket")
    ap.add_argument("--foxglove", action="store_true", help="the live Foxglove stream, a reading and a stalled client")
    ap.add_argument("--snapshots", type=float, default=0.0,
                    help="a record.snapshot every this many seconds: the flight recorder writing beside the loop")
    args = ap.parse_args()
    placement = ""
    daemon_options = ["--rt-priority", str(args.priority), "--stats-period", str(args.seconds)]
    if args.loop_cpu is not None:
        others = sorted(os.sched_getaffinity(0) - {args.loop_cpu})
        os.sched_setaffinity(0, others)  # inherited by the daemon's helpers and cyclictest
        daemon_options += ["--cpus", str(args.loop_cpu)]
        placement = f"; loop alone on CPU {args.loop_cpu}, the rest on {others}"
    if args.keys:
        daemon_options += with_keys()
        placement += "; CURVE keys on every socket"
    port = None
    if args.foxglove:
        port = free_tcp_port()
        daemon_options += ["--foxglove", f"127.0.0.1:{port}"]
        placement += "; Foxglove stream, one client reading every channel and one stalled"
    if args.snapshots:
        placement += f"; a flight snapshot every {args.snapshots:g} s"
    header(f"loop latency under full workload: {args.subscribers} subscriber(s), one stalled{placement}")
    daemon, eps = spawn_daemon(*daemon_options)
    ctx = zmq.Context.instance()
    try:
        client = Client(**eps, timeout=5.0)
        for attempt in range(12):  # a daemon starting on a busy machine may take more than one 5 s ping
            try:
                client.ping()
                break
            except TimeoutError:
                if attempt == 11:
                    raise
        stats_sub = stats_subscriber(eps)
        stop = threading.Event()
        first = f"{client.layout().owners()[0]}.setpoint"  # the set-point a set's effect shows in (the state's column)
        healthy = [Reader(ctx, eps["telemetry"], stop, keep=first if i == 0 else "")
                   for i in range(max(args.subscribers - 1, 0))]
        stalled = secure(ctx.socket(zmq.SUB))
        stalled.setsockopt(zmq.RCVHWM, 10)
        stalled.setsockopt(zmq.SUBSCRIBE, b"")
        if args.subscribers:
            stalled.connect(eps["telemetry"])
        fox = foxglove_clients(port, stop) if port else None
        client.acquire_lease()
        client.keep_lease()
        client.enable()
        time.sleep(0.5)
        messenger_cpu = MessengerCpu(daemon.pid)
        ct = cyclictest.start(args.seconds, args.priority)
        rtt, effects, trips = [], [], Trips()
        start = time.monotonic()
        n = 0
        snapshots, next_snapshot = 0, start + args.snapshots
        while time.monotonic() - start < args.seconds:
            if args.snapshots and time.monotonic() >= next_snapshot:
                client.record_snapshot()  # written by the recorder process a moment later
                snapshots, next_snapshot = snapshots + 1, next_snapshot + args.snapshots
            t0 = time.perf_counter()
            client.ping()
            rtt.append(time.perf_counter() - t0)
            n += 1
            if n % 4 == 0:
                client.status()
            if n % 40 == 0:
                target = [130.0 + (n // 40 % 2) * 2.0, -75.0]
                try:
                    reply = client.set(angles_deg=target)
                    effects.append((reply["cycle"], math.radians(target[0])))
                except RemoteError as exc:
                    if exc.code != "bad_state" or (exc.data or {}).get("reason") != "state":
                        raise
                    trips.again(client)  # the loop tripped (a stall on a loaded machine): said, and on
            time.sleep(0.004)
        messenger_s = messenger_cpu.seconds()
        transport = client.status()["transport"]
        ct_result = cyclictest.result(ct) if ct else None
        stats = None
        if stats_sub.poll(int((args.seconds + 5) * 1e3)):
            stats = msgpack.unpackb(stats_sub.recv_multipart()[1], raw=False)
        stop.set()
        for r in healthy:
            r.join()
        client.close()
        if fox is not None:
            fox[0].join()
            fox[1].close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    report(args, stats, ct_result, rtt, effects, healthy)
    print(f"transport counters        : {transport['counters'] or 'none'} over {transport['reads']} reads")
    print(f"trips during the run      : {trips.line()}")
    if args.snapshots:
        print(f"flight snapshots          : {snapshots} asked, one every {args.snapshots:g} s")
    if messenger_s is not None:
        print(f"messenger process CPU     : {messenger_s / args.seconds * 100:.1f} % of a core over the run")
    if fox is not None:
        print(f"Foxglove reading client   : {fox[0].messages} messages ({fox[0].messages / args.seconds:.0f}/s), "
              f"one client stalled throughout")


def foxglove_clients(port: int, stop: threading.Event):
    """A Foxglove client reading every channel (a process of its own: its decoding would
    otherwise take this process's GIL from the pings it times), and a stalled one."""
    from daemon.testing.foxglove_client import FoxgloveClient
    stalled = FoxgloveClient(port, stalled=True)
    stalled.subscribe(list(stalled.advertised(TOPICS)))
    return FoxgloveReader(port), stalled


TOPICS = ("/joint_states", "/pneumad/tracking", "/pneumad/loop")


class FoxgloveReader:
    def __init__(self, port: int):
        ctx = multiprocessing.get_context("spawn")
        self.count, self.done = ctx.Value("q", 0), ctx.Event()
        self.proc = ctx.Process(target=_read_foxglove, args=(port, self.count, self.done), daemon=True)
        self.proc.start()

    @property
    def messages(self) -> int:
        return self.count.value

    def join(self) -> None:
        self.done.set()
        self.proc.join(10)

    def close(self) -> None:
        pass


def _read_foxglove(port: int, count, done) -> None:
    from daemon.testing.foxglove_client import FoxgloveClient
    client = FoxgloveClient(port)
    client.subscribe(list(client.advertised(TOPICS)))
    n = 0
    while not done.is_set():
        if client.receive(0.2) is not None:
            n += 1
            if n % 100 == 0:
                count.value = n
    count.value = n
    client.close()


class MessengerCpu:
    """The messenger process's CPU time [s] from /proc, from now on (None where unreadable)."""

    def __init__(self, daemon_pid: int):
        self.pid = next((p for p in _children(daemon_pid) if b"daemon.messenger.process:serve" in _cmdline(p)), None)
        self.start = self._ticks()

    def _ticks(self):
        try:
            with open(f"/proc/{self.pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            return int(fields[11]) + int(fields[12])  # utime, stime
        except (OSError, TypeError, IndexError, ValueError):
            return None

    def seconds(self):
        now = self._ticks()
        return None if now is None or self.start is None else (now - self.start) / os.sysconf("SC_CLK_TCK")


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(p) for p in f.read().split()]
    except OSError:
        return []


def _cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read()
    except OSError:
        return b""


class Reader(threading.Thread):
    """A healthy subscriber: reads every state message and counts gaps in its sequence;
    ``keep``: the name of a set-point column whose values it keeps by cycle ("": none)."""

    def __init__(self, ctx, endpoint, stop, keep: str = ""):
        super().__init__(daemon=True)
        self.sock = secure(ctx.socket(zmq.SUB))
        self.sock.setsockopt(zmq.RCVHWM, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"state")
        self.sock.connect(endpoint)
        self.stop, self.keep = stop, keep
        self.messages, self.lost, self.setpoints = 0, 0, {}
        self.start()

    def run(self):
        last = None
        while not self.stop.is_set():
            if not self.sock.poll(100):
                continue
            m = msgpack.unpackb(self.sock.recv_multipart()[1], raw=False)
            if last is not None and m["seq"] != last + 1:
                self.lost += m["seq"] - last - 1
            last = m["seq"]
            self.messages += 1
            if self.keep:
                for c, sp in zip(m["cycle"], m[self.keep]):
                    self.setpoints[c] = sp
        self.sock.close(linger=0)


def effect_cycles(effects, setpoints) -> list[int]:
    """For each set command handled at cycle k, how many cycles until the set-point shows."""
    out = []
    for cycle, target in effects:
        later = [c for c in range(cycle, cycle + 50) if c in setpoints and abs(setpoints[c] - target) < 1e-9]
        if later:
            out.append(later[0] - cycle)
    return out


def fmt(d: dict) -> str:
    return "  ".join(f"{k} {d[k]:7.1f}" for k in ("p50", "p99", "p99.9", "max"))


def report(args, stats, ct, rtt, effects, healthy) -> None:
    if stats is None:
        print("no stats message from the daemon")
        return
    lat, comp = stats["latency_us"], stats["compute_us"]
    print(f"cycles {stats['cycles']}, overruns {stats['overruns']}, run {args.seconds:.0f} s, "
          f"priority {args.priority} (pid {os.getpid()})")
    print(f"loop wake-up latency us   : {fmt(lat)}")
    if ct:
        print(f"cyclictest latency us     : {fmt(ct)}   ({ct['samples']} samples)")
        print("ratio loop / cyclictest   : " + "  ".join(
            f"{k} {lat[k] / ct[k]:7.2f}" for k in ("p50", "p99", "p99.9", "max")))
    for stage in ("compute", "read", "control", "write", "telemetry", "commands", "total"):
        print(f"compute {stage:8s} us       : {fmt(comp[stage])}")
    r = percentiles([x * 1e6 for x in rtt])
    print(f"command round trip us     : {fmt(r)}   ({len(rtt)} pings over ipc)")
    cycles = effect_cycles(effects, healthy[0].setpoints) if healthy else []
    if cycles:
        print(f"set-point to effect       : max {max(cycles)} cycle(s), all {sorted(set(cycles))} ({len(cycles)} sets)")
    if healthy:
        print(f"healthy subscribers       : {len(healthy)}, messages {min(h.messages for h in healthy)}.."
              f"{max(h.messages for h in healthy)}, lost {sum(h.lost for h in healthy)}")


if __name__ == "__main__":
    main()
