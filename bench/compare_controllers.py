"""The controller comparison of docs/controllers.md, on the simulated rig through the real loop
(virtual clock): every built-in feedback controller on the thesis's two reference paths at the
thesis's durations (translation 15 s, circle 20 s: issue 32), beside the thesis's figures, then
on three paths none was tuned on (a vertical line, a figure-eight, a square) at durations the
planner accepts, a step per joint and a step disturbance torque per joint. The LTI controllers
run the shipped example design, controllers/designs/pi_thesis.toml (the thesis's PI as matrices).

    python -m bench.compare_controllers > docs/controllers-table.md   # and docs/images/compare-*.png
    python -m bench.compare_controllers --figures-only                # the translation runs and figures alone

Controllers whose translation runs a figure cannot tell apart (pid and lti, the same PI: within
1 % of each signal's range) are drawn once, named together in the legend ("pid ≈ lti"), never
one line hidden under another; every other run has a line style of its own.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import sys
from pathlib import Path

import numpy as np

from bench import scenarios as S
from controllers import trajectory
from daemon.client.plot_marks import merge_identical, start_and_direction

CONTROLLERS = ["pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]
STEPS_DEG = (10.0, 5.0)  # bottom, middle
THESIS = {"translation": (15.0, 3.3), "circle": (20.0, 3.5)}  # duration [s], best tip error reported [mm] (rig-facts §1)
UNSEEN = {  # name: (duration [s], maker(lengths, elbow, n, duration))
    "vertical line": (15.0, lambda L, e, n, d: trajectory.line(L, e, n, d, (30.0, 110.0), (30.0, 165.0), "vertical")),
    "figure-eight": (20.0, lambda L, e, n, d: trajectory.figure_eight(L, e, n, d)),
    "square": (20.0, lambda L, e, n, d: trajectory.cartesian_waypoints(
        L, e, n, [(20.0, 115.0), (70.0, 115.0), (70.0, 160.0), (20.0, 160.0), (20.0, 115.0)], [d / 4] * 4)),
}
STYLES = ("-", "--", "-.", (0, (5, 1, 1, 1, 1, 1)), (0, (3, 1)), (0, (8, 2)))  # a line style per run drawn


def unseen_path(loop, name: str):
    """The unseen path ``name`` at its duration, or at the shortest the rig's planner accepts
    if that is longer (to 0.1 s, up)."""
    duration, make = UNSEEN[name]
    path = make(loop.rig.arm.link_lengths_m, loop.rig.arm.elbow, loop.n, duration)
    shortest = S.authority(loop).shortest(path)
    if shortest and shortest > duration:
        path = make(loop.rig.arm.link_lengths_m, loop.rig.arm.elbow, loop.n, math.ceil(shortest * 10.0) / 10.0)
    return path


def translation(name: str, loop=None) -> dict:
    """The translation at the thesis's duration, every 20th cycle kept for the figures."""
    loop = loop or S.make_loop(name, options=S.example_options(name))
    trace = {"t": [], "ref": [], "q": [], "u": []}

    def keep(lp, i):  # every 20th cycle of the translation, for the figures
        if i % 20 == 0:
            trace["t"].append(i * lp.period)
            trace["ref"].append(list(lp.reference[0][:2]))
            trace["q"].append(list(lp.angles[:2]))
            trace["u"].append(list(lp.u[:2]))

    result = S.run_path(loop, S.make_path(loop, "translation", THESIS["translation"][0]), keep)
    middle = loop.actuation.commands[1]
    return {"name": name, "translation": result, "trace": trace, "lengths": list(loop.rig.arm.link_lengths_m),
            "u_limits": (middle.low, middle.high)}


def evaluate(name: str) -> dict:
    options = S.example_options(name)

    def fresh():
        return S.make_loop(name, options=options)

    loop = fresh()
    out = {"name": name, "circle_shortest_s": S.authority(loop).shortest(S.make_path(loop, "circle", 20.0)),
           "translation_shortest_s": S.authority(loop).shortest(S.make_path(loop, "translation", 15.0))}
    out.update(translation(name, loop))
    out["circle"] = S.run_path(fresh(), S.make_path(loop, "circle", THESIS["circle"][0]))
    for path in UNSEEN:
        lp = fresh()
        out[path] = S.run_path(lp, unseen_path(lp, path))
        out[path + " tripped"] = lp.state.value != "enabled"
    out["steps"] = [S.step_response(fresh(), j, STEPS_DEG[j], 20.0) for j in range(2)]
    torques = [m.kt * 1.0 for m in loop.context.models]
    out["rejection"] = [S.disturbance_rejection(fresh(), j, torques[j], 20.0) for j in range(2)]
    out["torques"] = torques
    return out


def table(results: list[dict]) -> str:
    first = results[0]
    lines = [f"The thesis's durations: translation {THESIS['translation'][0]:g} s (the rig's shortest accepted: "
             f"{first['translation_shortest_s']:.1f} s), circle {THESIS['circle'][0]:g} s (shortest: "
             f"{first['circle_shortest_s']:.1f} s).",
             "",
             "| controller | path | joint max (deg) bottom / middle | joint RMS (deg) | tip max (mm) | tip RMS (mm) "
             "| thesis, best tip (mm) |",
             "|---|---|---|---|---|---|---|"]
    for r in results:
        for path in ("translation", "circle"):
            t = r[path]
            lines.append(f"| {r['name']} | {path} {t.duration:.1f} s | {t.joint_max[0]:.2f} / {t.joint_max[1]:.2f} | "
                         f"{t.joint_rms[0]:.2f} / {t.joint_rms[1]:.2f} | {t.tip_max:.2f} | {t.tip_rms:.2f} | "
                         f"{THESIS[path][1]:g} |")
    lines += ["", "Paths none of the controllers was tuned on (vertical line (30, 110) -> (30, 165) mm; figure-eight "
              "about (40, 140) mm, 60 x 25 mm; square (20..70, 115..160) mm, a quarter of the time per side), at "
              "the durations shown (each the planned one, or the shortest the planner accepts if longer).", "",
              "| controller | path | joint max (deg) bottom / middle | tip max (mm) | tip RMS (mm) |",
              "|---|---|---|---|---|"]
    for r in results:
        for path in UNSEEN:
            t = r[path]
            trip = " (**tripped**)" if r[path + " tripped"] else ""
            lines.append(f"| {r['name']} | {path} {t.duration:.1f} s{trip} | {t.joint_max[0]:.2f} / "
                         f"{t.joint_max[1]:.2f} | {t.tip_max:.2f} | {t.tip_rms:.2f} |")
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


def figures(results: list[dict], out_dir: Path) -> list[Path]:
    """The translation run of every controller: tip paths against the reference, and the tip
    error [mm] and V_MV [V] against time [s]."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    fig_tip, ax_tip = plt.subplots(figsize=(9, 4.5))
    fig_err, (ax_err, ax_u) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    # pid and lti run the same PI (lti as matrices): their runs differ by 0.02 deg and 0.03 V, less
    # than a line's width, so one would hide the other: drawn once, both named
    drawn = merge_identical([r["name"] for r in results], [np.hstack([r["trace"]["q"], r["trace"]["u"]]) for r in results],
                            within=0.01)
    for k, (label, i) in enumerate(drawn):
        r = results[i]
        style = dict(color=f"C{k}", ls=STYLES[k % len(STYLES)], label=label)
        tr, (l1, l2) = r["trace"], r["lengths"][:2]
        ref, q = np.array(tr["ref"]), np.array(tr["q"])

        def tip(a):
            return (l1 * np.cos(a[:, 0]) + l2 * np.cos(a[:, 0] + a[:, 1])) * 1e3, \
                   (l1 * np.sin(a[:, 0]) + l2 * np.sin(a[:, 0] + a[:, 1])) * 1e3
        (rx, ry), (mx, my) = tip(ref), tip(q)
        if k == 0:
            ax_tip.plot(rx, ry, "k", ls=(0, (1, 2)), lw=1.0, label="reference")
            start_and_direction(ax_tip, rx, ry, np.array(tr["t"]), [], "k", "reference")
        ax_tip.plot(mx, my, lw=1.2, **style)
        ax_err.plot(tr["t"], np.hypot(rx - mx, ry - my), lw=1.1, **style)
        ax_u.plot(tr["t"], np.array(tr["u"])[:, 1], lw=1.0, **style)
    for v, text in zip(results[0]["u_limits"], ("V_MV limits", None)):
        ax_u.axhline(v, color="0.5", ls="--", lw=1.0, label=text)
    ax_tip.set(xlabel="x [mm]", ylabel="y [mm]", title="translation, 15 s: the tip on the simulated rig")
    ax_err.set(ylabel="tip error [mm]", title="translation, 15 s")
    ax_u.set(xlabel="time from the path's start [s]", ylabel="middle joint V_MV [V]")
    for ax in (ax_tip, ax_err, ax_u):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small", ncol=2)
    written = [out_dir / "compare-translation-tip.png", out_dir / "compare-translation-error.png"]
    for fig, path in zip((fig_tip, fig_err), written):
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("controllers", nargs="*", default=CONTROLLERS)
    parser.add_argument("--figures", default="docs/images", help="directory for the PNG figures (default docs/images)")
    parser.add_argument("--figures-only", action="store_true", help="the translation runs and the figures alone")
    args = parser.parse_args(argv)
    with multiprocessing.Pool(min(len(args.controllers), multiprocessing.cpu_count())) as pool:
        results = pool.map(translation if args.figures_only else evaluate, args.controllers)
    figures(results, Path(args.figures))
    if args.figures_only:
        return 0
    print(f"Produced by: python -m bench.compare_controllers {' '.join(args.controllers)}\n")
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
