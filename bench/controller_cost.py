"""Per-step cost of each built-in controller for the two joints of the built-in rig, and of the
muscle rig's controllers for its joint (``sim-muscle``, with measured pressures), and of the linear
axis's (``sim-axis``, mid-stroke).

    python -m bench.controller_cost

The LTI controllers run the shipped example design (the thesis's PI as matrices). Each controller is stepped on a recorded-looking state (the rig at rest with a moving
reference) for many cycles with the garbage collector off, as in the daemon; the figures are
p50 / p99 / max of one step, in microseconds.
"""
from __future__ import annotations

import gc
import math
import sys
import time

from bench.scenarios import example_options, make_loop
from controllers import registry
from controllers.base import JointState, Reference

CYCLES = 20000


def measure(name: str, context, angles) -> list[float]:
    controller = registry.build(name, context, options=example_options(name))
    zeros = [0.0] * context.n
    pressures = [2.0e5] * (2 * context.n)  # what a muscle pair's sensors read (a cylinder rig's controllers ignore it)
    controller.reset(JointState(0.0, angles, zeros, pressures), [0.0] * context.width)
    samples = []
    clock = time.perf_counter_ns
    for i in range(CYCLES):
        t = i * context.dt
        ref = Reference([a + 0.05 * math.sin(t) for a in angles], zeros, zeros)
        state = JointState(t, [a + 0.01 * math.sin(3 * t) for a in angles], zeros, pressures)
        t0 = clock()
        controller.step(state, ref)
        samples.append((clock() - t0) / 1e3)
    samples.sort()
    return [samples[len(samples) // 2], samples[int(len(samples) * 0.99)], samples[-1]]


def main() -> int:
    loop = make_loop("pid")
    gc.collect()
    gc.disable()  # as in the daemon, whose loop runs with the collector off
    print("Produced by: python -m bench.controller_cost")
    print(f"{'controller':10s} {'p50 us':>8s} {'p99 us':>8s} {'max us':>8s}")
    for name in ("hold", "pid", "smc", "smc_dob", "sac", "lti", "lti_dob"):
        p50, p99, worst = measure(name, loop.context, list(loop.angles))
        print(f"{name:10s} {p50:8.1f} {p99:8.1f} {worst:8.1f}")
    muscle = make_loop("muscle_eq", rig="sim-muscle")
    for name in ("muscle_eq", "muscle_pid"):
        p50, p99, worst = measure(name, muscle.context, [math.radians(45.0)])
        print(f"{name:10s} {p50:8.1f} {p99:8.1f} {worst:8.1f}")
    axis = make_loop("axis_pid", rig="sim-axis")
    for name in ("axis_pid", "axis_pva"):
        p50, p99, worst = measure(name, axis.context, [0.1])  # mid-stroke [m]
        print(f"{name:10s} {p50:8.1f} {p99:8.1f} {worst:8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
