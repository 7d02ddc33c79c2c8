"""The linear axis's controllers (``axis_pid``, ``axis_pva``) on ``sim-axis``: position steps and a
smooth trajectory, their figures in mm and a PNG (docs/controllers.md, "The linear axis").

Each controller runs the same requests, as a client sends them (``steps`` and ``waypoints`` in
mm, through the planner) on the daemon's loop on a virtual clock (deterministic: the plant steps
in lockstep with the loop):

- ``STEPS``: from 100 mm up to 150 mm, then down to 60 mm, each held ``HOLD_S``;
- ``PATH``: waypoints 60 -> 160 -> 60 mm, each leg a cubic of ``LEG_S`` (up to 100 mm/s).

Figures per step (:func:`step_figures`): rise time (10-90 %), settling time (into +-``BAND_MM``
of the new level for good), overshoot [% of the step], steady-state error [mm] (the mean over
the hold's last 0.5 s); on the trajectory (:func:`tracking_figures`): max and RMS error [mm]
while it runs. tests/test_axis_control.py asserts them on a real daemon beside two CPU hogs.

    python -m bench.axis_control --png docs/images/axis_control.png
"""
from __future__ import annotations

import argparse
import math

import numpy as np

START_MM = 100.0
STEPS = ([150.0], [60.0])  # the levels [mm]
HOLD_S = 2.5  # each level's hold [s]
PATH = ([60.0], [160.0], [60.0])  # waypoints [mm]
LEG_S = 1.5  # each leg [s]
BAND_MM = 1.0  # the settling band [mm]
CONTROLLERS = ("axis_pid", "axis_pva")
REQUESTS = (("steps", {"positions": [list(s) for s in STEPS], "hold_s": [HOLD_S] * len(STEPS)}),
            ("waypoints", {"positions": [list(p) for p in PATH], "durations_s": [LEG_S] * (len(PATH) - 1)}))


def step_figures(t, x_mm, t0: float, start_mm: float, level_mm: float, end_t: float, band_mm: float = BAND_MM) -> dict:
    """One step's figures from the samples ``t`` [s], ``x_mm`` [mm] of the step at ``t0`` from
    ``start_mm`` to ``level_mm``, held until ``end_t``; settled into +-``band_mm`` for good
    (NaN: not within the hold)."""
    t, x = np.asarray(t, float), np.asarray(x_mm, float)
    keep = (t >= t0) & (t < end_t)
    t, x = t[keep] - t0, x[keep]
    size = level_mm - start_mm
    y = (x - start_mm) / size  # the normalised response, 1 at the level
    rise = float(t[np.argmax(y >= 0.9)] - t[np.argmax(y >= 0.1)]) if (y >= 0.9).any() else math.nan
    outside = np.nonzero(np.abs(x - level_mm) > band_mm)[0]
    settle = float(t[outside[-1] + 1]) if outside.size and outside[-1] + 1 < t.size else (
        0.0 if not outside.size else math.nan)
    last = t >= t[-1] - 0.5
    return {"rise_s": rise, "settling_s": settle, "overshoot_pct": max(0.0, float(np.max(y)) - 1.0) * 100.0,
            "steady_state_error_mm": float(np.mean(level_mm - x[last]))}


def tracking_figures(t, x_mm, r_mm, t0: float, t1: float) -> dict:
    """Max and RMS of r - x [mm] over t0..t1 [s]."""
    t, e = np.asarray(t, float), np.asarray(r_mm, float) - np.asarray(x_mm, float)
    e = e[(t >= t0) & (t <= t1)]
    return {"max_error_mm": float(np.max(np.abs(e))), "rms_error_mm": float(np.sqrt(np.mean(e * e)))}


def figures(t, x_mm, r_mm, steps_t0: float, path_t0: float, path_t1: float, band_mm: float = BAND_MM) -> dict:
    """Every figure of one controller's run: ``steps`` (one dict per level) and ``path``."""
    levels, start = [], START_MM
    for k, level in enumerate(STEPS):
        t0 = steps_t0 + k * HOLD_S
        levels.append(step_figures(t, x_mm, t0, start, level[0], t0 + HOLD_S, band_mm))
        start = level[0]
    return {"steps": levels, "path": tracking_figures(t, x_mm, r_mm, path_t0, path_t1)}


def run(controller: str) -> dict:
    """The requests on ``sim-axis``'s loop on a virtual clock under ``controller``: the samples
    (t [s], x and r [mm]) and the figures."""
    from daemon.planner.commands import PLANNERS
    from daemon.planner.plans import PlanContext
    from daemon.testing.loop import virtual_loop
    from hal import config

    rig = config.load("sim-axis")
    loop = virtual_loop(rig, controller)
    ctx = PlanContext.of(rig, loop.context)
    t, x, r = [], [], []

    def advance(seconds: float) -> None:
        for _ in range(int(round(seconds / loop.period))):
            loop.run(1)
            t.append(loop.clock.now())
            x.append(loop.angles[0] * 1e3)
            r.append(loop.reference[0][0] * 1e3)

    try:
        loop.start()
        loop.enable()
        advance(0.2)

        def install(cmd: str, args: dict):
            """What the planner worker makes of a request, installed as the loop installs it."""
            p = PLANNERS[cmd](ctx, dict(args), list(loop.reference[0]))
            p.generation = loop.trajectory_generation
            loop.install(p)
            return p

        install("set", {"positions": [START_MM], "duration_s": 1.0})
        advance(2.5)
        marks = []
        for cmd, args in REQUESTS:
            marks.append(t[-1])
            p = install(cmd, args)
            advance(p.trajectory.duration + 1.0)
            assert loop.state.value == "enabled", loop.supervisor.cause
    finally:
        loop.shutdown("bench")
    marks.append(path_start(t, r, marks[1]))
    return {"t": t, "x_mm": x, "r_mm": r, "marks": marks,
            "figures": figures(t, x, r, marks[0], marks[2], marks[2] + (len(PATH) - 1) * LEG_S)}


def path_start(t, r_mm, after: float) -> float:
    """When the set-point leaves the path's first point after ``after`` [s]: the path's start,
    once the loop has held its start until the axis settled there (daemon.loop.settle)."""
    t, r = np.asarray(t, float), np.asarray(r_mm, float)
    moving = np.nonzero((t > after) & (np.abs(r - PATH[0][0]) > 1e-6))[0]
    return float(t[moving[0] - 1]) if moving.size else after


def table(results: dict[str, dict]) -> str:
    """The figures as docs/controllers.md's table."""
    rows = ["| controller | step | rise [s] | settling (+-1 mm) [s] | overshoot [%] | steady-state error [mm] |",
            "|---|---|---|---|---|---|"]
    for name, res in results.items():
        start = START_MM
        for level, f in zip(STEPS, res["figures"]["steps"]):
            rows.append(f"| `{name}` | {start:g} -> {level[0]:g} mm | {f['rise_s']:.3f} | {f['settling_s']:.2f} | "
                        f"{f['overshoot_pct']:.1f} | {f['steady_state_error_mm']:+.2f} |")
            start = level[0]
    rows += ["", "| controller | trajectory max error [mm] | RMS error [mm] |", "|---|---|---|"]
    for name, res in results.items():
        path = res["figures"]["path"]
        rows.append(f"| `{name}` | {path['max_error_mm']:.2f} | {path['rms_error_mm']:.2f} |")
    return "\n".join(rows)


def plot(results: dict[str, dict], path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex="col")
    for col, (lo, hi, title) in enumerate((("0", "1", "steps: 100 -> 150 -> 60 mm"),
                                           ("2", "end", "trajectory: 60 -> 160 -> 60 mm, 1.5 s legs"))):
        for k, (name, res) in enumerate(results.items()):
            t = np.asarray(res["t"])
            t0 = res["marks"][int(lo)]
            t1 = res["marks"][int(hi)] if hi != "end" else t0 + (len(PATH) - 1) * LEG_S + 0.5
            keep = (t >= t0 - 0.2) & (t <= t1)
            x, r = np.asarray(res["x_mm"])[keep], np.asarray(res["r_mm"])[keep]
            if k == 0:
                axes[0][col].plot(t[keep] - t0, r, "k--", lw=1, label="set-point")
            axes[0][col].plot(t[keep] - t0, x, lw=1.2, label=f"{name} position")
            axes[1][col].plot(t[keep] - t0, r - x, lw=1, label=name)
        axes[0][col].set_title(title)
        axes[0][col].set_ylabel("position [mm]")
        axes[1][col].set_ylabel("error r - x [mm]")
        axes[1][col].set_xlabel("time from the " + ("request" if col == 0 else "path's start") + " [s]")
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle("sim-axis (DSNU-25, MPYE-5-M5): axis_pid and axis_pva")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", help="write the figure here")
    args = parser.parse_args(argv)
    results = {name: run(name) for name in CONTROLLERS}
    print(table(results))
    if args.png:
        plot(results, args.png)


if __name__ == "__main__":
    main()
