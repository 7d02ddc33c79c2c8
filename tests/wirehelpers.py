"""Hardware-in-the-loop over a real wire: the simulated rig's peer in its own process, the
loop in this one on the real-time clock."""
from __future__ import annotations

import gc
import math
import os
import random
import subprocess
import sys
import time

from bench import wires
from bench.wires import stop_peer  # noqa: F401  (the tests stop peers through here too)
from controllers import trajectory
from daemon.loop.cycle import ControlLoop
from daemon.testing.loop import Captured
from daemon.testing.ports import free_tcp_port

# A shared, noisy test machine runs this loop without real-time priority, and stalls of tens
# (under load, hundreds) of milliseconds happen. A pipelined wire's sample dates from the
# request sent before the stall, so stale data trips at 1 s here (the rig file: 5 ms) and
# stalls at 2 s (50 ms; a loaded machine held this loop 1 s): what the tests see is the
# wire's behaviour, not the scheduler's.
RELAXED = {"stale_after_s": 1.0, "stall_after_s": 2.0}


PEER_NICE = -10  # a simulated device's niceness where the tests may set it (root: CI)


def start_peer(module: str, *args: str, ready) -> subprocess.Popen:
    """``python -m module args`` until ``ready()`` holds, ahead of ordinary processes where
    permitted (``PEER_NICE``): a peer stands for a device with a processor of its own (a bridge's
    microcontroller, a Modbus module), which no other program on the PC slows. Beside two CPU
    hogs the simulated serial bridge, at the hogs' priority, fell a second behind the daemon's
    1 kHz requests and the arm tripped on stale input: the machine's doing, not the daemon's.
    It waits on its socket between frames, so it takes no more than a device's share."""
    return wires.start_peer([sys.executable, "-m", module, *args], ready, nice=PEER_NICE)


def private_bus() -> tuple[str, int]:
    """A udp_multicast CAN bus of the test's own: a group and a UDP port nobody else uses (Linux
    hands a group's datagrams to every socket on the port: another test's bus on the same port,
    with another group, would hear this one)."""
    return f"239.74.{random.randrange(1, 255)}.{random.randrange(1, 255)}", free_tcp_port()


def as_device() -> None:
    """A ``preexec_fn`` giving a peer started otherwise (a README line) ``PEER_NICE`` where permitted."""
    try:
        os.nice(PEER_NICE)
    except OSError:
        pass


def wire_loop(backend: str | None, options: dict | None = None, virtual: bool = False):
    """The built-in rig through ``backend`` (None: in process), relaxed limits, telemetry captured."""
    gc.collect()
    gc.freeze()  # as the daemon does: a long test session's heap is not rescanned mid-move
    captured = Captured()
    loop = wires.wire_loop(backend, options, virtual, RELAXED, captured, spin_s=0.0)
    captured.follow(loop)
    return loop, captured


MOVE_DEG, MOVE_S = (4.0, 3.0), 2.0  # the move compared over a wire and in process


def move_and_track(loop: ControlLoop, offsets_deg=MOVE_DEG, duration_s: float = MOVE_S, tail_s: float = 1.0,
                   ages: list | None = None) -> list[float]:
    """Enable, move every joint by ``offsets_deg`` in ``duration_s`` (cubic scaling), and
    return the largest joint error seen [deg], per joint; each cycle's sample age [s] (how
    long ago the sample it used was taken) appended to ``ages`` if given."""
    loop.run(200)
    loop.enable()
    start = list(loop.reference[0])
    target = [a + math.radians(d) for a, d in zip(start, offsets_deg)]
    loop.set_trajectory(trajectory.JointMove(start, target, duration_s), "move")
    worst = [0.0] * loop.n
    for _ in range(int((duration_s + tail_s) / loop.period)):
        loop.run(1)
        worst = [max(w, abs(math.degrees(r - q))) for w, r, q in zip(worst, loop.reference[0], loop.angles)]
        if ages is not None:
            ages.append(loop.clock.now() - loop.io.transport.health().last_sample_t)
    return worst


def tracks_like_in_process(loop: ControlLoop):
    """Move over the wire, then the same move in process on the virtual clock: the largest
    joint errors agree within 0.5 deg, and what the wire's late samples explain: a sample
    ``g`` old (the machine starved the peer or this loop) leaves the controller up to ``g``
    behind a reference moving at the move's top speed (1.5 offset / duration, a cubic's).
    Returns the wire's health after the move."""
    ages = []
    try:
        over_wire = move_and_track(loop, ages=ages)
        assert loop.state.value == "enabled", loop.supervisor.cause
        health = loop.io.transport.health()
    finally:
        loop.shutdown()  # a failing move must not leave its transport (and a worker process) open
    in_process = move_and_track(wire_loop(None, virtual=True)[0])
    late = max(ages)
    allowed = [0.5 + 1.5 * d / MOVE_S * late for d in MOVE_DEG]
    assert all(abs(w - p) < a for w, p, a in zip(over_wire, in_process, allowed)), (over_wire, in_process, late)
    return health


def trip_and_recover(loop: ControlLoop, kill, restart, back) -> tuple[int, str]:
    """Enabled and holding, ``kill()`` the peer and count the cycles to the trip. Then: the
    loop keeps its period while in fault; ``restart()`` the peer and run until ``back()``;
    the safe state goes out; reset and enable work again. Returns (cycles, cause)."""
    loop.run(200)
    loop.enable()
    loop.run(200)
    kill()
    for cycles in range(1, 2000):
        loop.run(1)
        if loop.state.value == "fault":
            break
    assert loop.state.value == "fault", "no trip"
    cause = loop.supervisor.cause
    cycle = loop.cycle
    loop.run(300)
    assert loop.cycle == cycle + 300 and loop.state.value == "fault"
    restart()
    deadline = time.monotonic() + 120  # the peer's restart is waited for, however busy the machine
    while not back():
        assert time.monotonic() < deadline, "the peer never came back"
        loop.run(1)
    loop.run(100)
    assert tuple(loop.io.last_volts) == tuple(loop.io.safe_volts) and loop.state.value == "fault"
    loop.reset()
    loop.enable()
    loop.run(300)
    assert loop.state.value == "enabled", loop.supervisor.cause
    return cycles, cause
