"""``pneumactl evaluate``: controllers on the rig's model over references and plant variations,
faster than real time, on every core, before they touch the arm (docs/controllers.md).

    python -m evaluation CONTROLLER [CONTROLLER ...] | --all [--param K=V ...] [--config RIG]
        [--reference NAME|FILE ...] [--plants nominal|thesis|grid|FILE] [--out DIR] [--quiet]

The first controller named takes the ``--param`` values (its parameters, as ``controller set``
takes them); the others run beside it at their defaults. A controller is a built-in, an
installed plugin (entry point ``pneumad.controllers``), a controller directory's file
(``--controller-dir``, the rig file's ``[rig] controller_dirs``) or a ``module:Class`` path. Each case is
the daemon's own loop on a virtual clock (:mod:`evaluation.runner`).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from controllers import registry
from daemon import assembly
from controllers.base import ControllerContext, ParamError
from evaluation import cases, fast, pool, report, runner
from hal import config
from hal.actuation import RigActuation
from hal.errors import ConfigError


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pneumactl evaluate", description=__doc__.splitlines()[0])
    p.add_argument("controllers", nargs="*", metavar="CONTROLLER")
    p.add_argument("--all", action="store_true",
                   help=f"every built-in cylinder controller ({', '.join(cases.BUILTINS)})")
    p.add_argument("--param", action="append", default=[], metavar="K=V", help="a parameter of the first controller")
    p.add_argument("--config", help="rig file or built-in rig name (default: the built-in simulated rig)")
    p.add_argument("--reference", nargs="+", metavar="NAME|FILE",
                   help=f"{', '.join(cases.PATHS)} or a waypoint CSV (default: the robustness grid's paths)")
    p.add_argument("--plants", default="nominal", help="nominal, thesis, grid or a TOML file of [[plants]]")
    p.add_argument("--out", default="evaluation", help="directory for table.md, cases.csv and the PNGs")
    p.add_argument("--jobs", type=int, default=os.cpu_count(), help="worker processes (default: every core)")
    p.add_argument("--controller-dir", action="append", default=[], metavar="DIR",
                   help="a directory of controller plugin files, as the daemon's (docs/writing-controllers.md); "
                        "the rig file's [rig] controller_dirs are read too")
    p.add_argument("--engine", choices=("auto", "fast", "loop"), default="auto",
                   help="fast: the loop's cycle compiled around the controller; loop: the daemon's loop itself "
                        "(the reference); auto: fast where it applies")
    return p


def check(rig, controllers: list[str], params: dict, references: list[str] | None, engine: str,
          plant: cases.Plant, plugins: dict[str, str] | None = None) -> str:
    """Build each controller and each reference once here, and the fast engine when it may run:
    a bad name, parameter or file, or an engine that does not apply, is refused before any
    worker starts. The engine the cases will run on, in words."""
    cases.check_rig(rig)
    why = ""
    if engine != "loop":
        try:
            loop = runner.make_loop(runner.evaluation_rig(rig, plant, True), "hold", None, None)
            why = fast.refusal(loop)
            if not why:
                fast.FastLoop(loop, 1).compile()  # here: the workers, forked after it, have it compiled
        except ConfigError as exc:  # no compiled plant for this rig
            if engine == "fast":
                raise
            why = f"the compiled plant ({exc})"
        if why and engine == "fast":
            raise ValueError(f"--engine fast needs {why} (--engine loop runs any rig the simulator has)")
    context = ControllerContext.for_rig(rig, RigActuation(rig), 0.001)
    for controller in controllers:
        registry.build(controller, context, params if controller == controllers[0] else None,
                       runner.construction_options(controller), plugins)
    for name in references or []:
        cases.reference(rig, context, name)
    if engine == "loop" or why:
        return "on the daemon's loop" + (f" (the fast engine needs {why})" if why else "")
    return "on the fast engine"


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    controllers = list(dict.fromkeys(args.controllers))
    if args.all:
        controllers = cases.BUILTINS + [c for c in args.controllers if c not in cases.BUILTINS]
    if not controllers:
        parser().error("name a controller, or --all")
    pool.one_blas_thread()  # the checks below build every controller and a loop, as the workers do
    try:
        params = dict(config.parse_option(p, "--param") for p in args.param)
        rig = config.load(args.config)
        plugins: dict[str, str] = {}
        dirs = assembly.controller_dirs(args, rig, plugins)
        for refused in dirs.refused:
            print(f"pneumactl evaluate: controller file {refused['file']} refused: {refused['error']}", file=sys.stderr)
        plants = cases.plants(args.plants, rig)
        running = check(rig, controllers, params, args.reference, args.engine, plants[0], plugins)
    except (ConfigError, ParamError, LookupError, ValueError, OSError) as exc:
        print(f"pneumactl evaluate: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results, elapsed = pool.run(rig, controllers, params, plants, args.reference, args.engine, args.jobs, dirs)
    report.write_csv(results, out / "cases.csv")
    table = report.summary(results, controllers)
    lines = report.failures(results)
    text = (f"{len(results)} cases ({len(controllers)} controllers, {len(plants)} plants) in {elapsed:.0f} s "
            f"on {args.jobs} processes, {running}\n\n{table}\n")
    if lines:
        text += f"\nTripped or not settled ({len(lines)} cases):\n" + "\n".join(lines) + "\n"
    (out / "table.md").write_text(text)
    pictures = report.figures(results, controllers, [j.name for j in rig.joints], out)
    print(text)
    print(f"written: {out / 'table.md'}, {out / 'cases.csv'}, " + ", ".join(str(p) for p in pictures))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # the pool's workers ended with it (they ignore Ctrl-C)
        print("interrupted: the evaluation stopped; its results are written only once every case has run",
              file=sys.stderr)
        sys.exit(130)
