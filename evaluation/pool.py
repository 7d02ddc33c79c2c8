"""Every case of an evaluation on every core: a process pool, the longest cases first."""
from __future__ import annotations

import math
import multiprocessing
import os
import signal
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

from controllers.base import ControllerContext
from controllers.directory import Directories
from evaluation import cases, runner
from hal.actuation import RigActuation


def one_blas_thread() -> None:
    """One BLAS thread in this process: a case's designs (the plant's ZOH, the controllers'
    Riccati equations) are small matrices, on which OpenBLAS's threads, spinning beside the
    other worker's on the same cores, cost about ten times the CPU of one thread (0.12 against
    0.013 s to set up an smc_dob case on this VM)."""
    threadpool_limits(1)


def _start_worker(sources) -> None:
    """A worker's start: one BLAS thread; Ctrl-C ignored (sent to the whole process group, it
    is the parent's to stop the workers, with one line); the controller directories' files
    arrive executed (:class:`controllers.directory.Source` unpickles so), for their
    controllers to build."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as the parent had it when it forked them; a spawned one too
    one_blas_thread()


def _work(task) -> runner.Case:
    """One case in a worker; an error of its own (not a trip: those are the case's figures) is
    its ``tripped`` cause, so one case's failure names itself and the others still run."""
    rig, controller, params, plant, name, trace, engine, plugins = task
    label = Path(name).name if name not in cases.PATHS else name
    try:
        context = ControllerContext.for_rig(rig, RigActuation(rig), 0.001)
        path = cases.reference(rig, context, name)
        return runner.run_case(rig, controller, plant, label, path, params, runner.construction_options(controller),
                               plugins, engine=engine, trace=trace)
    except Exception as exc:  # noqa: BLE001 - reported in the table, never silent
        return runner.Case(controller, plant.name, label, math.nan, tripped=f"evaluation failed: "
                           f"{type(exc).__name__}: {exc}")


def tasks(rig, controllers: list[str], params: dict, plants: list[cases.Plant], references: list[str] | None,
          engine: str = "auto", plugins: dict[str, str] | None = None):
    """Every case, the longest first (the pool stays busy to the end), the controllers on one
    plant and reference one after another (a worker samples the reference once for them)."""
    out = []
    for controller in controllers:
        for k, plant in enumerate(plants):
            for name in references or cases.default_references(plant):
                out.append((rig, controller, params if controller == controllers[0] else None, plant, name, k == 0,
                            engine, plugins))
    weight = {"translation": 0, "circle": 1, "figure-eight": 2, "square": 3, "line": 4, "steps": 5}
    return sorted(out, key=lambda t: (weight.get(t[4], -1), plants.index(t[3]), controllers.index(t[1])))


def run(rig, controllers: list[str], params: dict, plants: list[cases.Plant], references: list[str] | None,
        engine: str = "auto", jobs: int | None = None, dirs: Directories | None = None
        ) -> tuple[list[runner.Case], float]:
    """Every case (controllers x plants x references; the robustness grid's paths when none are
    named), in controller then plant order, and the wall time they took [s]. ``dirs``: the
    controller directories' files, whose controllers may be among ``controllers``."""
    plugins = dirs.plugins() if dirs is not None else None
    work = tasks(rig, controllers, params, plants, references, engine, plugins)
    start = time.monotonic()
    sources = tuple(dirs.sources.values()) if dirs is not None else ()
    calm = signal.signal(signal.SIGINT, signal.SIG_IGN)  # the workers start ignoring Ctrl-C, whenever it comes
    try:
        workers = multiprocessing.Pool(max(1, jobs or os.cpu_count()), _start_worker, (sources,))
    finally:
        signal.signal(signal.SIGINT, calm)
    with workers:
        results = workers.map(_work, work, chunksize=1)
    elapsed = time.monotonic() - start
    names = [p.name for p in plants]
    results.sort(key=lambda c: (controllers.index(c.controller), names.index(c.plant)))
    return results, elapsed
