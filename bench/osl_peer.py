"""The closest pure-Python peer, opensourceleg's SoftRealtimeLoop at 1 ms, running the same
work per iteration as the daemon's loop (simulated rig read, PID, write), with cyclictest.

Run it in a throwaway environment (opensourceleg is not a dependency of pneumad):
    python3 -m venv /tmp/osl && /tmp/osl/bin/pip install opensourceleg -e .
    chrt -f 80 /tmp/osl/bin/python -m bench.osl_peer --seconds 30
Its default mode sleeps relative to the previous iteration's start and then spins; wake-up
latency is measured against that target (previous start + dt), the peer's own schedule.
"""
from __future__ import annotations

import argparse
import os
import time

from bench import cyclictest
from bench.common import header, percentiles
from controllers.base import JointState, Reference
from daemon import assembly
from hal import config
from hal.rig import PressureDrivers

try:
    from opensourceleg.time import SoftRealtimeLoop
except ImportError:
    from opensourceleg.utilities import SoftRealtimeLoop


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--priority", type=int, default=80)
    args = ap.parse_args()
    header("opensourceleg SoftRealtimeLoop (dt 1 ms) with the daemon's per-cycle work")
    rig = config.load()
    drivers = PressureDrivers.of(rig)
    io = assembly.open_rig(rig, time.monotonic, drivers)
    parts = assembly.loop_parts(rig, 0.001, "pid", drivers=drivers)
    act, pid = parts.actuation, parts.controller
    q0 = list(io.read().angles)
    zeros = [0.0, 0.0]
    pid.reset(None, zeros)
    ct = cyclictest.start(args.seconds, args.priority)
    loop = SoftRealtimeLoop(dt=0.001, report=False)
    lateness, compute = [], []
    previous = None
    end = time.monotonic() + args.seconds
    for _ in loop:
        wake = time.monotonic()
        if previous is not None:
            lateness.append((wake - (previous + 0.001)) * 1e6)
        previous = wake
        snap = io.read()
        u = pid.step(JointState(snap.t, snap.angles, zeros), Reference(q0, zeros, zeros))
        io.write_pressures(*act.outputs(u))
        compute.append((time.monotonic() - wake) * 1e6)
        if wake > end:
            loop.stop()
    lat = percentiles(lateness)
    print(f"scheduling: {os.sched_getscheduler(0)} (1 = SCHED_FIFO), {len(lateness)} iterations")
    print("peer wake-up latency us   : " + "  ".join(f"{k} {v:7.1f}" for k, v in lat.items()))
    print("peer compute us           : " + "  ".join(f"{k} {v:7.1f}" for k, v in percentiles(compute).items()))
    if ct:
        c = cyclictest.result(ct)
        print("cyclictest latency us     : " + "  ".join(f"{k} {c[k]:7.1f}" for k in ("p50", "p99", "p99.9", "max")))
        print("ratio peer / cyclictest   : " + "  ".join(f"{k} {lat[k] / c[k]:7.2f}" for k in ("p50", "p99", "p99.9", "max")))


if __name__ == "__main__":
    main()
