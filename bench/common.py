"""Shared bench helpers: timing statistics and the header every bench prints."""
from __future__ import annotations

import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager

import zmq

from daemon.wire import keys
from daemon.client.client import Client
from daemon.testing import daemons


def header(title: str) -> None:
    """Print what produced the figures: the command, the machine, the interpreter."""
    print(f"# {title}")
    print(f"command: python {shlex.join(sys.orig_argv[1:])}")
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, "
          f"{platform.python_implementation()} {platform.python_version()}, {time.strftime('%Y-%m-%d')}")


def percentiles(samples: list[float], points=(50, 99, 99.9)) -> dict[str, float]:
    """Nearest-rank percentiles and the maximum of ``samples``."""
    ordered = sorted(samples)
    n = len(ordered)
    out = {f"p{p:g}": ordered[min(n - 1, max(0, int(round(p / 100.0 * n + 0.5)) - 1))] for p in points}
    out["max"] = ordered[-1]
    return out


def per_call_us(fn, repeat: int, rounds: int = 5) -> float:
    """Best-of-rounds mean time per call [us] (the least disturbed round on a shared machine)."""
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, (time.perf_counter() - t0) / repeat)
    return best * 1e6


def spawn_daemon(*options: str) -> tuple[subprocess.Popen, dict[str, str]]:
    """A real ``pneumad run`` on private ipc endpoints (the simulated rig), and the endpoints."""
    return daemons.spawn(tempfile.mkdtemp(prefix="pneumad-bench-"), *options)


@contextmanager
def leased_daemon(*options: str, timeout: float = 10.0):
    """A real ``pneumad`` (see :func:`spawn_daemon`), a client holding its lease (kept alive)
    and a subscriber to its ``stats``; the daemon is stopped on the way out."""
    daemon, eps = spawn_daemon(*options)
    try:
        client = Client(**eps, timeout=timeout)
        wait_answering(client, daemon)
        stats = stats_subscriber(eps)
        client.acquire_lease()
        client.keep_lease()
        try:
            yield client, stats
        finally:
            client.close()
    finally:
        daemon.terminate()
        daemon.wait(daemons.STOP_WAIT_S)


def wait_answering(client: Client, daemon: subprocess.Popen, limit_s: float = 60.0) -> None:
    """Ping until the daemon just started answers: on a busy machine its start (the imports,
    the helpers) takes more than one ping's wait (10 s seen beside other work)."""
    deadline = time.monotonic() + limit_s
    while True:
        if daemon.poll() is not None:
            raise RuntimeError(f"pneumad exited with {daemon.returncode} before it answered")
        try:
            client.call("ping", timeout=2.0)
            return
        except TimeoutError:
            if time.monotonic() > deadline:
                raise


def with_keys() -> tuple[str, ...]:
    """CURVE for a bench: a fresh key directory with an operator key, that key in
    ``PNEUMAD_KEY`` (the Client and :func:`secure` use it), and the daemon's options."""
    directory = tempfile.mkdtemp(prefix="pneumad-bench-keys-")
    keys.init_server(os.path.join(directory, "server"))
    os.environ["PNEUMAD_KEY"] = keys.make_client(os.path.join(directory, "server"), "bench", keys.OPERATOR, directory)
    return "--keys", os.path.join(directory, "server")


def secure(sock: zmq.Socket) -> zmq.Socket:
    """A raw socket of a bench, given the key in ``PNEUMAD_KEY`` if there is one."""
    if os.environ.get("PNEUMAD_KEY"):
        keys.secure_client(sock, os.environ["PNEUMAD_KEY"])
    return sock


def stats_subscriber(eps: dict[str, str]) -> zmq.Socket:
    """A SUB socket on the daemon's ``stats`` topic."""
    sock = secure(zmq.Context.instance().socket(zmq.SUB))
    sock.setsockopt(zmq.SUBSCRIBE, b"stats")
    sock.connect(eps["telemetry"])
    return sock


def child_process(parent: int, marker: str) -> int | None:
    """The pid of a child of ``parent`` whose command line holds ``marker`` (e.g. the daemon's
    messenger, ``daemon.messenger.process``), or None."""
    for pid in map(int, filter(str.isdigit, os.listdir("/proc"))):
        try:
            with open(f"/proc/{pid}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmdline = f.read()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == parent and marker.encode() in cmdline:
            return pid
    return None


class Trips:
    """The trips a bench's daemon met while loaded, told instead of ending the bench: a
    stall trip on a loaded machine is one of the bench's results. ``again(client)`` after a
    command was refused because the arm was not enabled: the cause noted from ``status``, then
    reset and enable, so the load goes on."""

    def __init__(self):
        self.causes: list[str] = []

    def again(self, client: Client) -> None:
        status = client.status()
        self.causes.append(f"{status['cause'] or status['state']} [cycle {status['cycle']}]")
        client.reset()
        client.enable()

    def line(self) -> str:
        if not self.causes:
            return "none"
        return f"{len(self.causes)}, the figures include them: " + "; ".join(self.causes[:5]) + (
            f"; ... {len(self.causes) - 5} more" if len(self.causes) > 5 else "")

