"""One loop cycle measured hot: the code's own cost, without the machine's noise.

Usage: python -m bench.cycle_cost [--cycles 20000]

Runs the daemon's loop (built-in simulated rig, PID enabled, telemetry rows recorded, the
server's per-cycle poll with no requests) back to back on a virtual clock, so caches stay
warm and nothing else runs between cycles; then times the parts of a cycle the same way.
Against the loop's compute figures in real time (bench.loop_latency, ``pneumad latency``)
this separates what the code costs from what a busy machine adds to it.
"""
from __future__ import annotations

import argparse
import gc
import threading
import time

from bench.common import header
from controllers.base import JointState, Reference
from controllers.experiment import InputExperiment
from controllers.signals import Multisine
from daemon.loop.clock import VirtualClock
from daemon.assembly import cycle_layout, loop_from_args
from daemon.main import parser
from daemon.loop.port import ZmqServer
from hal import config


def per_call_us(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def watchdog_guards(loop, n: int) -> None:
    """What the cycle watchdog (daemon/loop/watchdog.py) adds to a cycle, against the lock it
    does without: its guards as the loop runs them (in_io around the read and the write, made
    only while held is None; the controller stepping named; the cycle boundary's look at held),
    each minus the same calls bare, in alternation; and two takes of an uncontended lock."""
    lock, nothing = threading.Lock(), (lambda: None)

    def bare():
        nothing(), nothing(), nothing()

    def guarded():
        loop.in_io = True
        try:
            if loop.held is None:
                nothing()
        finally:
            loop.in_io = False
        loop.stepping = loop.controller
        nothing()
        loop.stepping = None
        if loop.held is None:
            loop.in_io = True
            try:
                if loop.held is None:
                    nothing()
            finally:
                loop.in_io = False
        if loop.held is not None:
            nothing()

    def locked():
        with lock:
            nothing()
        nothing()
        with lock:
            nothing()

    added, taken = [], []
    for _ in range(5):
        base = per_call_us(bare, n)
        added.append(per_call_us(guarded, n) - base)
        taken.append(per_call_us(locked, n) - base)
    print(f"{'  watchdog guards (median of 5, minus bare)':45s} {sorted(added)[2]:6.3f} us")
    print(f"{'  (two lock takes instead, the same way)':45s} {sorted(taken)[2]:6.3f} us")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=20000)
    n = ap.parse_args().cycles
    header("one loop cycle, hot, on a virtual clock (simulated rig, PID, telemetry, command poll)")
    clock = VirtualClock()
    server = ZmqServer("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", "tcp://127.0.0.1:*",
                       layout=cycle_layout(config.load()))
    try:
        loop = loop_from_args(parser().parse_args(["run"]), clock, server.publish, server.stats_banks)
        server.attach(loop)
        gc.collect()
        gc.freeze()
        gc.disable()
        loop.start()
        loop.enable()

        def cycle():
            loop.run(1)

        parts = {
            "whole cycle (loop.run(1))": cycle,
            "  read: sim plant step + sensors + drivers": lambda: (clock.sleep_until(clock.t + 0.001), loop.io.read()),
            "  check: measurement filter + supervisor": lambda: (
                loop._update_measurement(loop.snapshot),
                loop.supervisor.check(loop.snapshot.angles, loop.velocities, (), 0.0)),
            "  control: reference + PID": lambda: loop._control(clock.t),
            "  write: pressures, clamps, drivers, DAC": loop._write_command,
            "  cycle record (the layout's spans)": lambda: loop._record(loop.snapshot),
            "  telemetry row (the record packed)": lambda: loop.telemetry.record(loop),
            "  command poll (nothing pending)": lambda: server.poll(loop.cycle),
        }
        cycle_state = JointState(0.0, loop.angles, loop.velocities), Reference(*loop.reference)
        parts["    of which PID step"] = lambda: loop.controller.step(*cycle_state)
        parts["    of which tracking rule (lost + stuck)"] = lambda: loop.tracking.check(clock.t, loop.reference[0],
                                                                                      loop.angles)
        for name, fn in parts.items():
            per_call_us(fn, n // 10)  # warm
            print(f"{name:45s} {per_call_us(fn, n):6.2f} us")
        watchdog_guards(loop, n)
        # an open-loop experiment in progress: the largest signal excite allows (a 32-sine
        # multisine) and the centring PI, instead of the reference's sample alone
        signal = Multisine([0.0], 0, 0.3, 0.05, 20.0, Multisine.MAX_COMPONENTS, 600.0)
        loop.set_trajectory(InputExperiment(list(loop.reference[0]), 0, signal, 0.01, (-10.0, 10.0), {}, (0.5, 0.1)),
                            "multisine-input")
        loop.run(50)  # past its settling
        control = lambda: loop._control(clock.t)  # noqa: E731
        per_call_us(control, n // 10)
        print(f"{'  control: + input multisine (32 sines)':45s} {per_call_us(control, n):6.2f} us")
        gc.enable()
    finally:
        server.close()


if __name__ == "__main__":
    main()
