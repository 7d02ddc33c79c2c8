"""Every built-in controller at the rig's edges: the reference paths and unseen ones, on the
nominal plant and on the corners of the thesis's uncertainty set, with the rig's sensor noise.

The runner is ``pneumactl evaluate``'s (:mod:`evaluation`: the daemon's loop on a virtual clock,
its cycle compiled around the controller, equal to the loop's own; its protocol and figures in
:mod:`evaluation.runner`), over the robustness grid (:func:`evaluation.cases.grid`: plant gain
K_mdl x0.41..x1.41 per joint, friction and viscous terms (Fs, Fc, D) x0.7..x1.5, dead time
T_dly x0.8..x1.2; its 16 corners, plus the nominal plant with and without noise). Any
controller ``pneumactl evaluate`` takes runs here: a built-in, an installed plugin or a
``module:Class`` path. This table keeps the bench's own columns (nominal, noise-free and noisy).

    python -m bench.robustness [--controllers pid smc] [--quick] [--csv docs/robustness.csv]
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from evaluation import cases, pool, report
from evaluation.cases import Plant  # noqa: F401 - the benches' and tests' name for a plant variation
from hal import config

CONTROLLERS = cases.BUILTINS


def paths(loop, with_circle: bool) -> dict:
    """The grid's references on ``loop``'s rig, by name (the circle when asked)."""
    names = [p for p in cases.PATHS if p != "steps" and (with_circle or p != "circle")]
    return {name: cases.reference(loop.rig, loop.context, name) for name in names}


def summary(results, controllers: list[str]) -> str:
    """One row per controller and path: nominal figures, the worst over the grid, counts."""
    lines = ["| controller | path | tip max nominal (mm) | tip max worst (mm) | tip RMS worst (mm) | joint max worst (deg) "
             "| at limit nominal / worst (%) | motion noise-free / noisy / worst (V/s) | sign changes worst (1/s) "
             "| recovered | error 8 s after, worst (deg) | tripped |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    keys = list(dict.fromkeys((c.controller, c.reference) for c in results))
    for controller, path in sorted(keys, key=lambda k: controllers.index(k[0])):
        group = [c for c in results if (c.controller, c.reference) == (controller, path)]
        nominal = next(c for c in group if c.plant == "nominal")
        clean = next(c for c in group if c.plant == "nominal, no noise")
        ran = [c for c in group if not c.tripped]

        def worst(attr):
            return max((getattr(c, attr) for c in ran), default=math.nan)

        lines.append(f"| {controller} | {path} {nominal.duration_s:.1f} s | {nominal.tip_max_mm:.2f} | {worst('tip_max_mm'):.2f} "
                     f"| {worst('tip_rms_mm'):.2f} | {worst('joint_max_deg'):.2f} "
                     f"| {nominal.at_limit_pct:.1f} / {worst('at_limit_pct'):.1f} "
                     f"| {clean.motion_v_s:.1f} / {nominal.motion_v_s:.1f} / {worst('motion_v_s'):.1f} "
                     f"| {worst('sign_changes_per_s'):.1f} | {sum(c.recovered for c in group)}/{len(group)} "
                     f"| {worst('final_deg'):.2f} | {sum(bool(c.tripped) for c in group)}/{len(group)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", nargs="*", default=CONTROLLERS, help="built-ins or plugins (default: the built-ins)")
    parser.add_argument("--quick", action="store_true", help="equal gains on both joints only (8 corners)")
    parser.add_argument("--csv", help="write every case here")
    args = parser.parse_args(argv)
    grid = cases.grid(args.quick)
    rig = config.load()
    results, elapsed = pool.run(rig, args.controllers, {}, grid, None)
    if args.csv:
        report.write_csv(results, Path(args.csv))
    print(f"Produced by: python -m bench.robustness {' '.join(sys.argv[1:] if argv is None else argv)}")
    print(f"({len(results)} cases over {len(grid)} plants in {elapsed:.0f} s; the circle runs on the "
          "nominal plant only)\n")
    print(summary(results, args.controllers))
    failed = report.failures(results)
    if failed:
        print(f"\nNot bounded or not recovered ({len(failed)} cases):")
        print("\n".join(failed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
