"""The controller comparison of docs/controllers.md, on the simulated rig through the real loop
(virtual clock): every built-in feedback controller on both reference paths, a step per joint
and a step disturbance torque per joint. The LTI controllers run the shipped example design,
controllers/designs/pi_thesis.toml (the thesis's PI as matrices).

    python -m bench.compare_controllers > docs/controllers-table.md
"""
from __future__ import annotations

import argparse
import multiprocessing
import sys

from bench import scenarios as S

CONTROLLERS = ["pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]
STEPS_DEG = (10.0, 5.0)  # bottom, middle


def evaluate(name: str) -> dict:
    options = S.example_options(name)

    def fresh():
        return S.make_loop(name, options=options)

    loop = fresh()
    circle_s = S.shortest_feasible(loop, "circle")
    out = {"name": name, "circle_s": circle_s}
    out["translation"] = S.run_path(loop, S.make_path(loop, "translation", 15.0))
    out["circle"] = S.run_path(fresh(), S.make_path(loop, "circle", circle_s))
    out["steps"] = [S.step_response(fresh(), j, STEPS_DEG[j], 20.0) for j in range(2)]
    torques = [m.kt * 1.0 for m in loop.context.models]
    out["rejection"] = [S.disturbance_rejection(fresh(), j, torques[j], 20.0) for j in range(2)]
    out["torques"] = torques
    return out


def table(results: list[dict]) -> str:
    lines = [f"Circle period: {results[0]['circle_s']:.1f} s, the shortest the simulated rig's authority allows.",
             "",
             "| controller | path | joint max (deg) bottom / middle | joint RMS (deg) | tip max (mm) | tip RMS (mm) |",
             "|---|---|---|---|---|---|"]
    for r in results:
        for path in ("translation", "circle"):
            t = r[path]
            lines.append(f"| {r['name']} | {path} {t.duration:.1f} s | {t.joint_max[0]:.2f} / {t.joint_max[1]:.2f} | "
                         f"{t.joint_rms[0]:.2f} / {t.joint_rms[1]:.2f} | {t.tip_max:.2f} | {t.tip_rms:.2f} |")
    lines += ["", f"Steps of {STEPS_DEG[0]:g} deg (bottom) and {STEPS_DEG[1]:g} deg (middle) from rest; settling into "
              "+-5 % for good (20 s: did not settle in the run).", "",
              "| controller | joint | rise 10-90 % (s) | overshoot (%) | settling (s) |", "|---|---|---|---|---|"]
    for r in results:
        for j, s in enumerate(r["steps"]):
            lines.append(f"| {r['name']} | {('bottom', 'middle')[j]} | {s.rise:.2f} | {s.overshoot:.1f} | {s.settling:.2f} |")
    lines += ["", "Step disturbance torque of one volt's worth (kt x 1 V: "
              f"{results[0]['torques'][0]:.3f} N m bottom, {results[0]['torques'][1]:.3f} N m middle) while holding; "
              "recovery back within 0.5 deg for good.", "",
              "| controller | joint | peak deviation (deg) | recovery (s) |", "|---|---|---|---|"]
    for r in results:
        for j, d in enumerate(r["rejection"]):
            lines.append(f"| {r['name']} | {('bottom', 'middle')[j]} | {d.peak:.2f} | {d.recovery:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("controllers", nargs="*", default=CONTROLLERS)
    args = parser.parse_args(argv)
    with multiprocessing.Pool(min(len(args.controllers), multiprocessing.cpu_count())) as pool:
        results = pool.map(evaluate, args.controllers)
    print(f"Produced by: python -m bench.compare_controllers {' '.join(args.controllers)}\n")
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
