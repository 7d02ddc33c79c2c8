"""Where ``pneumactl evaluate``'s time goes: CPU per simulated cycle of one case (the translation
on the nominal plant: approach, settle, 15 s, hold) with each engine, per controller, and the
CPU the robustness grid (``--all --plants grid``: 444 cases) needs at those costs.

    python -m bench.evaluation_cost [--controllers hold pid smc ...] [--no-loop]

``hold`` (which repeats the output it took over) gives the fast engine's own cost a cycle; a
controller's row less that is its step. The grid's cycles are counted from its cases' own
durations (approach, settle, reference, hold). Process CPU time (``time.process_time``), each
case run twice and the second taken: numba's compilation or cache load is the first's, and the
second finds the reference's samples the first kept, as most of the grid's cases do.
"""
from __future__ import annotations

import argparse
import time

from bench.common import header
from controllers.base import ControllerContext
from evaluation import cases, pool, runner
from hal import config
from hal.actuation import RigActuation

CONTROLLERS = ["hold", "pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]


def cpu_per_cycle(rig, context, controller: str, engine: str) -> float:
    """[us] a cycle of the translation case, the second of two runs."""
    path = cases.reference(rig, context, "translation")
    loop = runner.make_loop(runner.evaluation_rig(rig, cases.Plant("nominal"), False), controller, None,
                            runner.construction_options(controller))
    start = path.sample(0.0)[0]
    cycles = round((runner.approach_duration(loop, start) + runner.SETTLE_S + path.duration + runner.HOLD_S) / 0.001)
    for _ in range(2):
        t = time.process_time()
        runner.run_case(rig, controller, cases.Plant("nominal"), "translation", path,
                        options=runner.construction_options(controller), engine=engine)
        spent = time.process_time() - t
    return spent / cycles * 1e6


def grid_cycles(rig, context) -> tuple[int, int]:
    """(cases, cycles) of one controller over the robustness grid."""
    n_cases = n_cycles = 0
    for plant in cases.grid():
        for name in cases.default_references(plant):
            path = cases.reference(rig, context, name)
            loop = runner.make_loop(runner.evaluation_rig(rig, plant, False), "hold", None, None)
            approach = runner.approach_duration(loop, path.sample(0.0)[0])
            n_cycles += round((approach + runner.SETTLE_S) / 0.001) + round((path.duration + runner.HOLD_S) / 0.001)
            n_cases += 1
    return n_cases, n_cycles


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", nargs="*", default=CONTROLLERS)
    parser.add_argument("--no-loop", action="store_true", help="the fast engine only")
    args = parser.parse_args(argv)
    header("pneumactl evaluate: CPU per simulated cycle, one translation case")
    pool.one_blas_thread()  # as in the evaluation's workers
    rig = config.load()
    context = ControllerContext.for_rig(rig, RigActuation(rig), 0.001)
    per_case, cycles = grid_cycles(rig, context)
    print(f"the grid: {per_case} cases and {cycles / 1e6:.2f} M cycles a controller")
    print("controller   fast us/cycle   loop us/cycle   grid CPU at fast (s)")
    total = 0.0
    for controller in args.controllers:
        fast = cpu_per_cycle(rig, context, controller, "fast")
        loop = float("nan") if args.no_loop else cpu_per_cycle(rig, context, controller, "loop")
        grid_s = fast * cycles * 1e-6
        total += grid_s if controller in cases.BUILTINS else 0.0
        print(f"{controller:10s} {fast:13.1f} {loop:15.1f} {grid_s:18.0f}")
    print(f"the grid's built-ins at the fast engine's cost: {total:.0f} s of CPU, {total / 2:.0f} s on 2 cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
