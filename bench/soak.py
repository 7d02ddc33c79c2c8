"""A soak: a real daemon at full telemetry for a long time, under everything a lab does to it.

Usage: python -m bench.soak [--seconds 3600] [--no-rt] [--kill-every 300]

Three healthy subscribers, one slow (50 ms a message) and one stalled (never reads) on every
topic; a client holding the lease runs the translation path again and again, switches
controllers (pid <-> smc) and changes a gain every few seconds; the messenger process is
killed every ``--kill-every`` s. Figures, goal in brackets: sequence gaps at the healthy
subscribers outside the seconds after a messenger kill [0] (a kill loses what was in
flight, by design: docs/protocol.md); the daemon's resident memory at the end against the
mark at a sixth of the run [within a few MiB]; trips and their causes [none that a fault
did not cause: the driver resets and re-enables after each, so one trip does not end the
soak]; overruns, against the machine's own noise (see docs/benchmarks.md); what the driver did.
"""
from __future__ import annotations

import argparse
import os
import signal
import threading
import time
from dataclasses import dataclass, field

import msgpack
import zmq

from bench.common import header, spawn_daemon
from daemon.client.client import Client, RemoteError
from daemon.testing.daemons import STOP_WAIT_S

KILL_SHADOW_S = 5.0  # a gap this soon after a messenger kill is the kill's


@dataclass
class Watch:
    """One subscriber's count of messages and sequence gaps (time, messages missing)."""

    delay_s: float = 0.0
    messages: int = 0
    gaps: list[tuple[float, int]] = field(default_factory=list)


def subscribe(eps: dict[str, str], watch: Watch | None, stop: threading.Event) -> threading.Thread | zmq.Socket:
    """A subscriber on every topic: read by a thread into ``watch``, or (None) never read."""
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(eps["telemetry"])
    if watch is None:
        return sock

    def read():
        last: dict[bytes, int] = {}
        while not stop.is_set():
            if not sock.poll(100):
                continue
            topic, body = sock.recv_multipart()
            seq = msgpack.unpackb(body, raw=False).get("seq")
            if topic in last and seq is not None and seq > last[topic] + 1:
                watch.gaps.append((time.monotonic(), seq - last[topic] - 1))
            last[topic] = seq
            watch.messages += 1
            if watch.delay_s:
                time.sleep(watch.delay_s)
        sock.close()

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    return thread


def rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def messenger_restarts(client: Client, at_least: int, limit_s: float = 60.0) -> int:
    """The daemon's count of messenger restarts once it reaches ``at_least`` (or ``limit_s``
    has passed): a killed messenger is back at its own pace, seconds on a busy machine, and
    the next kill (or the final count) waits for it rather than hit a process not yet reaped."""
    deadline = time.monotonic() + limit_s
    while True:
        try:
            seen = client.call("status", timeout=5.0)["telemetry"]["messenger_restarts"]
        except TimeoutError:
            seen = -1  # the request went down with the messenger: ask the new one
        if seen >= at_least or time.monotonic() > deadline:
            return seen
        time.sleep(0.2)


def soak(daemon_pid: int, eps: dict[str, str], seconds: float, kill_every: float, min_kills: int = 0) -> dict:
    """Drive the daemon for ``seconds``, killing its messenger every ``kill_every`` once the last
    kill's restart is done, and on past ``seconds`` until ``min_kills`` kills have been made (a
    loaded machine restarts a messenger slowly), for at most ten times ``seconds``; the report."""
    stop = threading.Event()
    healthy = [Watch() for _ in range(3)]
    slow = Watch(delay_s=0.05)
    readers = [subscribe(eps, w, stop) for w in (*healthy, slow)]
    stalled = subscribe(eps, None, stop)
    client = Client(**eps, timeout=5.0)
    done = {"paths": 0, "switches": 0, "gain_changes": 0, "kills": 0, "timeouts": 0, "refused": 0}
    trips: list[str] = []  # causes, in order; the driver resets and re-enables after each
    kills: list[float] = []
    rss = {}
    try:
        client.call("ping", timeout=60.0)
        client.acquire_lease(ttl_s=10.0)
        client.keep_lease(0.5)
        client.enable()
        start = time.monotonic()
        next_kill, tick = start + kill_every, 0
        while ((now := time.monotonic()) - start < seconds
               or (done["kills"] < min_kills and now - start < 10 * seconds)):
            if "mark" not in rss and now - start >= seconds / 6:
                rss["mark"] = rss_mib(daemon_pid)
            try:
                state = client.status()
                if state["state"] == "fault":  # note the cause, and carry on soaking
                    trips.append(state["cause"])
                    client.reset()
                    client.enable()
                if tick % 10 == 0:
                    client.abort()
                    client.path("translation")
                    done["paths"] += 1
                elif tick % 10 in (3, 6):
                    client.switch_controller("smc" if client.controller()["name"] == "pid" else "pid")
                    done["switches"] += 1
                elif tick % 10 == 8 and client.controller()["name"] == "pid":
                    client.set_params(Kp=[45.0 + tick % 20, 50.0])
                    done["gain_changes"] += 1
            except TimeoutError:
                done["timeouts"] += 1  # a request in flight through a messenger kill
            except RemoteError:
                done["refused"] += 1
            if now >= next_kill and messenger_restarts(client, at_least=done["kills"]) >= done["kills"]:
                pid = client.status()["helpers"]["messenger"]["pid"]  # the one in service, not its spare
                if pid is not None:
                    os.kill(pid, signal.SIGKILL)
                    kills.append(now)
                    done["kills"] += 1
                next_kill += kill_every
            tick += 1
            time.sleep(2.0)
        messenger_restarts(client, at_least=done["kills"])  # the last kill's restart, however slow
        status = client.call("status", timeout=10.0)
        rss["end"] = rss_mib(daemon_pid)
    finally:
        client.close()
        stop.set()
        for reader in readers:
            reader.join(2.0)
        stalled.close()

    def outside_kills(watch: Watch) -> int:
        return sum(n for t, n in watch.gaps if not any(k <= t <= k + KILL_SHADOW_S for k in kills))

    return {"seconds": seconds, "healthy_messages": [w.messages for w in healthy],
            "healthy_gaps": [sum(n for _, n in w.gaps) for w in healthy],
            "healthy_gaps_outside_kills": [outside_kills(w) for w in healthy], "slow_messages": slow.messages,
            "rss_mark_mib": rss.get("mark", float("nan")), "rss_end_mib": rss["end"], "trips": status["trips"],
            "trip_causes": trips + ([status["cause"]] if status["state"] == "fault" else []),
            "overruns": status["overruns_total"],
            "messenger_restarts": status["telemetry"]["messenger_restarts"], **done}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=3600.0)
    ap.add_argument("--kill-every", type=float, default=300.0)
    ap.add_argument("--no-rt", action="store_true")
    args = ap.parse_args()
    header("soak")
    daemon, eps = spawn_daemon(*(["--no-rt"] if args.no_rt else []))
    try:
        report = soak(daemon.pid, eps, args.seconds, args.kill_every)
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    for key, value in report.items():
        print(f"{key:28s} {value}")


if __name__ == "__main__":
    main()
