"""Every built-in controller over the thesis's own uncertainty ranges (issue 32), holding a
set-point and on the translation at the thesis corner.

    python -m bench.thesis_corners [--controllers pid smc] [--hold-s 10] [--csv FILE]

The ranges, per joint (rig-facts §1 "Robust-control view" and the issue): plant gain K_mdl
x0.41..x1.41 on the bottom joint and x0.59..x1.41 on the middle one; friction (Fs, Fc) and
damping (D) each x0.5..x1.5; dead time x1.0..x1.5. The grid is every corner (2^5 = 32) and the
nominal plant, each with the rig's sensor noise. The true plant changes
(:class:`bench.robustness.Plant`); the controllers keep their nominal models; the daemon's
supervisor and its tracking rule are ON, as on the rig: a trip is what the lab would see.

Per controller and plant: the arm, enabled and holding where it rests, for ``--hold-s``; any
trip is named with its cause. Then the translation in 15 s at the thesis corner (gain 0.41
bottom / 0.59 middle, friction and damping x1.5), tip max [mm].
"""
from __future__ import annotations

import argparse
import csv
import itertools
import multiprocessing
import sys
import time

from bench import scenarios as S
from bench.robustness import CONTROLLERS, Plant

GAINS = ((0.41, 1.41), (0.59, 1.41))  # per joint: bottom, middle (rig-facts §1: K_min, K_max)
FACTORS = (0.5, 1.5)  # friction (Fs, Fc) and damping (D), each
DELAYS = (1.0, 1.5)
THESIS_CORNER = Plant("thesis corner: gain 0.41/0.59, friction x1.5, damping x1.5", (0.41, 0.59), 1.5, 1.0,
                      damping=1.5)


def grid() -> list[Plant]:
    out = [Plant("nominal")]
    for gb, gm, f, d, t in itertools.product(GAINS[0], GAINS[1], FACTORS, FACTORS, DELAYS):
        out.append(Plant(f"gain {gb:g}/{gm:g}, friction x{f:g}, damping x{d:g}, delay x{t:g}", (gb, gm), f, t,
                         damping=d))
    return out


def hold(args) -> dict:
    """Enabled and holding on ``plant`` for ``seconds``: the trip's cause, or ''."""
    controller, plant, seconds = args
    loop = S.make_loop(controller, options=S.example_options(controller), plant=plant.sim_options())
    loop.hold()
    for _ in range(int(seconds * 10)):
        loop.run(100)
        if loop.state.value != "enabled":
            break
    return {"controller": controller, "plant": plant.name,
            "tripped": "" if loop.state.value == "enabled" else loop.supervisor.cause}


def corner_translation(controller: str) -> dict:
    loop = S.make_loop(controller, options=S.example_options(controller), plant=THESIS_CORNER.sim_options(),
                       replace=S.NO_TRACKING_RULE)
    result = S.run_path(loop, S.make_path(loop, "translation", 15.0))
    return {"controller": controller, "tip_max_mm": result.tip_max, "joint_max_deg": max(result.joint_max),
            "tripped": "" if loop.state.value == "enabled" else loop.supervisor.cause}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", nargs="*", default=CONTROLLERS)
    parser.add_argument("--hold-s", type=float, default=10.0)
    parser.add_argument("--csv", help="write every holding case here")
    args = parser.parse_args(argv)
    plants = grid()
    start = time.monotonic()
    with multiprocessing.Pool(multiprocessing.cpu_count()) as pool:
        held = pool.map(hold, [(c, p, args.hold_s) for c in args.controllers for p in plants], chunksize=1)
        corner = pool.map(corner_translation, args.controllers)
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["controller", "plant", "tripped"])
            writer.writeheader()
            writer.writerows(held)
    print(f"Produced by: python -m bench.thesis_corners {' '.join(sys.argv[1:] if argv is None else argv)}")
    print(f"({len(held)} holding cases over {len(plants)} plants, {args.hold_s:g} s each, and the translation at "
          f"the thesis corner, in {time.monotonic() - start:.0f} s)\n")
    print("| controller | trips while holding (of %d plants) | translation 15 s at the thesis corner: tip max (mm) "
          "| joint max (deg) |" % len(plants))
    print("|---|---|---|---|")
    for c, tr in zip(args.controllers, corner):
        trips = [h for h in held if h["controller"] == c and h["tripped"]]
        print(f"| {c} | {len(trips)} | {tr['tip_max_mm']:.2f}{' (tripped)' if tr['tripped'] else ''} "
              f"| {tr['joint_max_deg']:.2f} |")
    trips = [h for h in held if h["tripped"]]
    if trips:
        print(f"\nTrips while holding ({len(trips)}):")
        for h in trips:
            print(f"- {h['controller']}, {h['plant']}: {h['tripped']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
