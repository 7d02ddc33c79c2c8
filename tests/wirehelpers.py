"""Hardware-in-the-loop over a real wire: the simulated rig's peer in its own process, the
loop in this one on the real-time clock."""
from __future__ import annotations

import math
import subprocess
import sys
import time
from dataclasses import replace

from controllers import trajectory
from daemon.clock import MonotonicClock, VirtualClock
from daemon.loop import ControlLoop
from daemon.telemetry import Telemetry
from hal import config
from hal.rig import RigIO
from hal.transport import create_transport
from tests.loophelpers import Captured

# A shared, noisy test machine runs this loop without real-time priority: stale data and
# stalls trip at 50 ms and 0.5 s here instead of the rig file's 5 ms and 50 ms, so what the
# tests see is the wire's behaviour, not the scheduler's.
RELAXED = {"stale_after_s": 0.05, "stall_after_s": 0.5}


def start_peer(module: str, *args: str, ready, timeout_s: float = 20.0) -> subprocess.Popen:
    """``python -m module args`` until ``ready()`` holds; the process."""
    proc = subprocess.Popen([sys.executable, "-m", module, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + timeout_s
    while not ready():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"{module} did not come up: {proc.stdout.read().decode(errors='replace')}")
        time.sleep(0.05)
    return proc


def stop_peer(proc: subprocess.Popen, hard: bool = False) -> None:
    proc.kill() if hard else proc.terminate()
    proc.wait(10)
    proc.stdout.close()


def wire_loop(backend: str | None, options: dict | None = None, virtual: bool = False):
    """The built-in rig through ``backend`` (None: the in-process simulator), started."""
    rig = config.load()
    if backend is not None:
        rig = config.with_transport(rig, backend, options or {})
    rig = replace(rig, safety=replace(rig.safety, **RELAXED))
    clock = VirtualClock() if virtual else MonotonicClock(spin_s=0.0)
    transport = create_transport(rig, clock.now)
    transport.open()
    captured = Captured()
    loop = ControlLoop(RigIO(rig, transport), clock, 0.001, controller="pid", telemetry=Telemetry(captured))
    loop.start()
    return loop, captured


def move_and_track(loop: ControlLoop, offsets_deg=(4.0, 3.0), duration_s: float = 2.0, tail_s: float = 1.0) -> list[float]:
    """Enable, move every joint by ``offsets_deg`` in ``duration_s`` (cubic scaling), and
    return the largest joint error seen [deg], per joint."""
    loop.run(200)
    loop.enable()
    start = list(loop.reference[0])
    target = [a + math.radians(d) for a, d in zip(start, offsets_deg)]
    loop.set_trajectory(trajectory.JointMove(start, target, duration_s), "move")
    worst = [0.0] * loop.n
    for _ in range(int((duration_s + tail_s) / loop.period)):
        loop.run(1)
        worst = [max(w, abs(math.degrees(r - q))) for w, r, q in zip(worst, loop.reference[0], loop.angles)]
    return worst
