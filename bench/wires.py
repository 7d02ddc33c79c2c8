"""The simulated rig behind each real wire, for benches and tests: how to start each peer
process, and a loop in this process that reaches the rig through the wire."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

from daemon import assembly
from daemon.loop.clock import MonotonicClock, VirtualClock
from daemon.loop.cycle import ControlLoop
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.ports import free_tcp_port
from hal import config


@dataclass(frozen=True)
class Wire:
    """A transport to the simulated rig: its peer's command line, the daemon's transport
    options, and when the peer is ready (None: the host's open() waits for it)."""

    backend: str
    options: dict
    peer: list[str]
    ready: Callable[[], bool] | None = None


def listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def wires(tmp: str) -> dict[str, Wire]:
    """Every built-in wire, on fresh endpoints (a link under ``tmp``, a free port, a group)."""
    link, port, rtu_port = os.path.join(tmp, "bridge"), free_tcp_port(), free_tcp_port()
    group = f"239.74.{os.getpid() % 250 + 1}.{int(time.time()) % 250 + 1}"
    py = [sys.executable, "-m"]
    return {
        "serial": Wire("serial", {"port": link}, [*py, "sim_backend.serial_peer", "--link", link],
                       lambda: os.path.exists(link)),
        "modbus-tcp": Wire("modbus", {"port": port}, [*py, "sim_backend.modbus_peer", "--port", str(port)],
                           lambda: listening(port)),
        "modbus-rtu": Wire("modbus", {"mode": "rtu", "device": f"socket://127.0.0.1:{rtu_port}"},
                           [*py, "sim_backend.modbus_peer", "--port", str(rtu_port), "--framer", "rtu"],
                           lambda: listening(rtu_port)),
        "can-udp": Wire("can", {"interface": "udp_multicast", "channel": group, "open_timeout_s": 20.0},
                        [*py, "sim_backend.can_peer", "--interface", "udp_multicast", "--channel", group]),
    }


def start_peer(command: list[str], ready: Callable[[], bool] | None, timeout_s: float = 20.0,
               priority: int = 0, nice: int = 0) -> subprocess.Popen:
    """Start a peer process (at SCHED_FIFO ``priority`` if > 0, else with ``nice`` added to its
    niceness, each if permitted) and wait until ``ready()``."""
    def scheduling():
        try:
            if priority > 0:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            elif nice:
                os.nice(nice)
        except OSError:
            pass
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, preexec_fn=scheduling)
    deadline = time.monotonic() + timeout_s
    while ready is not None and not ready():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"{command} did not come up: {proc.stdout.read().decode(errors='replace')}")
        time.sleep(0.05)
    return proc


def stop_peer(proc: subprocess.Popen, hard: bool = False) -> None:
    proc.kill() if hard else proc.terminate()
    proc.wait(STOP_WAIT_S)
    proc.stdout.close()


def wire_loop(backend: str | None, options: dict | None = None, virtual: bool = False,
              safety: dict | None = None, publish=None, spin_s: float = 200e-6) -> ControlLoop:
    """The built-in rig through ``backend`` (None: the in-process simulator), PID, started;
    its telemetry to ``publish`` if given."""
    rig = config.load()
    if backend is not None:
        rig = config.with_transport(rig, backend, options or {})
    if safety:
        rig = replace(rig, safety=replace(rig.safety, **safety))
    clock = VirtualClock() if virtual else MonotonicClock(spin_s)
    loop = assembly.build_loop(rig, clock, 0.001, "pid", publish=publish, contact=False)
    loop.start()
    return loop
