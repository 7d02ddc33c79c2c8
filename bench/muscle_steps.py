"""The muscle rig's step responses against the chapter's settling times (rig-facts §2), and the
stiffness test: a tip-load step on the held joint deflects it by load torque / stiffness.

    python -m bench.muscle_steps [--plot docs/images] [--controller muscle_eq]

Each case runs the real control loop on the built-in ``sim-muscle`` rig on a virtual clock:
the arm is brought to the start angle and held there for HOLD_S (the integral takes up a tip
load the model does not know), then the set-point steps (duration 0) and the angle is
recorded for RECORD_S. Settling: the last time the angle is outside +-5 % of the step.

The chapter's step experiments hang the tip loads on the arm; the model is not told of them
(``tip_load`` 0) and the joint is position-controlled (``compliant`` 0): the integral brings
the loaded arm to its set-point, which is why a heavier load, or a softer joint, settles
later. The stiffness test runs the default, compliant controller: there the load's step is
meant to deflect the joint, by exactly load torque / commanded stiffness.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from bench.common import header
from bench.scenarios import make_loop
from controllers import trajectory

HOLD_S = 4.0  # at the start angle before the step [s]
RECORD_S = 5.0  # after it [s]
GOAL_BAND = 0.05  # settling band, of the step
STEPS = ((0, 45), (0, 90), (45, 0), (45, 90), (90, 0), (90, 45))
# (label, start, end [deg], stiffness [N m/deg], tip load [N], the chapter's simulation and experiment [s])
CASES = (
    [(f"step {a} -> {b} deg", a, b, 0.3, 0.0, sim, exp) for (a, b), (sim, exp) in
     zip(STEPS, ((0.815, 1.125), (0.958, 1.073), (0.708, 1.287), (0.743, 1.614), (0.828, 1.225), (0.764, 0.92)))]
    + [(f"tip load {f:g} N (0 -> 90 deg)", 0, 90, 0.3, f, sim, exp) for f, sim, exp in
       ((0.0, 0.958, 1.073), (8.33, 1.102, 1.45), (16.66, 1.567, 2.009))]
    + [(f"stiffness {k:g} N m/deg (16.66 N, 0 -> 45 deg)", 0, 45, k, 16.66, sim, exp) for k, sim, exp in
       ((0.2, 2.59, 3.19), (0.5, 1.439, 1.78))]
)
# the goals of the issue, per group of rows: the range between the chapter's simulated and measured times
GOALS = {"step": (0.71, 1.61), "tip load": (0.96, 2.01), "stiffness 0.2": (2.6, 3.2), "stiffness 0.5": (1.4, 1.8)}
STIFFNESS_TEST = ((45.0, 0.2, 4.0), (45.0, 0.5, 8.33), (60.0, 0.5, 16.66))  # angle [deg], N m/deg, load step [N]


def goal_of(label: str) -> tuple[float, float]:
    return next(v for k, v in GOALS.items() if label.startswith(k))


def loaded_loop(controller: str, load_n: float, params: dict):
    return make_loop(controller, params, rig="sim-muscle", plant={"muscle": {"tip_load_n": load_n}})


def hold_at(loop, angle_deg: float, stiffness_nm_deg: float, seconds: float) -> None:
    q = [math.radians(angle_deg)]
    loop.set_trajectory(trajectory.JointMove(list(loop.reference[0]), q, 1.0), "approach",
                        stiffness=[stiffness_nm_deg * 180 / math.pi])
    loop.run(int((1.0 + seconds) / loop.period))


def step_case(controller: str, start: float, end: float, stiffness: float, load: float):
    """(times [s], angles [deg], pressures a, b [MPa]) after the step, and its settling time [s]
    (infinite when the supervisor tripped)."""
    loop = loaded_loop(controller, load, {"compliant": [0.0]} if controller == "muscle_eq" else None)
    hold_at(loop, start, stiffness, HOLD_S)
    loop.set_trajectory(trajectory.JointMove([math.radians(start)], [math.radians(end)], 0.0), "step")
    t, q, pa, pb = [], [], [], []
    for i in range(int(RECORD_S / loop.period)):
        loop.run(1)
        t.append(i * loop.period)
        q.append(math.degrees(loop.angles[0]))
        pa.append(loop.pressures[0] * 1e-6)
        pb.append(loop.pressures[1] * 1e-6)
        if not loop.supervisor.enabled:  # tripped: the safe state ends the case
            return (t, q, pa, pb), math.inf
    return (t, q, pa, pb), settling(t, q, start, end)


def settling(t, q, start: float, end: float) -> float:
    band = GOAL_BAND * abs(end - start)
    last = 0.0
    for ti, qi in zip(t, q):
        if abs(qi - end) > band:
            last = ti
    return last


def stiffness_case(controller: str, angle: float, stiffness: float, load: float):
    """Hold ``angle`` with ``stiffness``, hang ``load`` [N] on the tip: (the deflection
    [deg], the one load torque / stiffness predicts at the deflected angle [deg], trace)."""
    loop = loaded_loop(controller, 0.0, None)
    hold_at(loop, angle, stiffness, HOLD_S)
    joint = loop.io.transport.arm.joint
    joint.tip_load_n = load
    t, q = [], []
    for i in range(int(2 * RECORD_S / loop.period)):
        loop.run(1)
        t.append(i * loop.period)
        q.append(math.degrees(loop.angles[0]))
    final = sum(q[-500:]) / 500
    load_torque = -load * joint.model.length_m * math.sin(math.radians(final))  # the load's moment [N m]
    predicted = math.degrees(load_torque / (stiffness * 180 / math.pi))
    return final - angle, predicted, (t, q)


def figures(traces: dict, deflections: dict, out: Path, controller: str) -> list[Path]:
    """Three PNGs: the plain steps, the tip loads and stiffness cases, the stiffness test."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    groups = (("muscle-steps", "step", "Steps, no load (stiffness 0.3 N m/deg)"),
              ("muscle-loads", ("tip load", "stiffness"), "Tip loads (0 -> 90 deg) and stiffness (16.66 N, 0 -> 45 deg)"))
    for name, prefix, title in groups:
        fig, (ax_q, ax_p) = plt.subplots(2, 1, figsize=(9, 7), sharex=True, height_ratios=(2, 1))
        for label, (t, q, pa, pb) in traces.items():
            if not label.startswith(prefix):
                continue
            line, = ax_q.plot(t, q, lw=1.3, label=label)
            end = next(c[2] for c in CASES if c[0] == label)
            start = next(c[1] for c in CASES if c[0] == label)
            band = GOAL_BAND * abs(end - start)
            ax_q.axhspan(end - band, end + band, color=line.get_color(), alpha=0.08)
            ax_p.plot(t, pa, color=line.get_color(), lw=1.0)
            ax_p.plot(t, pb, ":", color=line.get_color(), lw=1.0)
        ax_q.set_ylabel("joint angle [deg]")
        ax_q.set_title(f"{title}\n{controller}; shaded: the +-5 % band", fontsize=11)
        ax_q.legend(fontsize=8, loc="lower right")
        ax_q.grid(alpha=0.3)
        ax_p.set_ylabel("muscle pressure [MPa]\n(solid a, dotted b)")
        ax_p.set_xlabel("time after the step [s]")
        ax_p.grid(alpha=0.3)
        fig.tight_layout()
        written.append(out / f"{name}.png")
        fig.savefig(written[-1], dpi=100)
        plt.close(fig)
    if deflections:
        fig, ax = plt.subplots(figsize=(9, 4.5))
        for (angle, stiffness, load), (t, q) in deflections.items():
            ax.plot(t, [v - angle for v in q], lw=1.3, label=f"held at {angle:g} deg, {stiffness:g} N m/deg, +{load:g} N")
        ax.set_xlabel("time after the tip load is hung [s]")
        ax.set_ylabel("deflection from the set-point [deg]")
        ax.set_title("Stiffness test: the compliant controller under a tip-load step")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        written.append(out / "muscle-stiffness.png")
        fig.savefig(written[-1], dpi=100)
        plt.close(fig)
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.muscle_steps", description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="muscle_eq", choices=("muscle_eq", "muscle_pid"))
    ap.add_argument("--plot", default=None, metavar="DIR", help="write the responses as PNGs into DIR")
    args = ap.parse_args(argv)
    header(f"muscle rig: step responses against the chapter's settling times ({args.controller})")
    print("| case | settling [s] | chapter: simulation / experiment [s] | goal [s] | met |")
    print("|---|---|---|---|---|")
    traces, misses = {}, 0
    for label, start, end, stiffness, load, sim, exp in CASES:
        trace, ts = step_case(args.controller, start, end, stiffness, load)
        lo, hi = goal_of(label)
        met = lo <= ts <= hi
        misses += not met
        traces[label] = trace
        shown = f"{ts:.3f}" if ts < math.inf else "tripped"
        print(f"| {label} | {shown} | {sim} / {exp} | {lo}-{hi} | {'yes' if met else 'NO'} |", flush=True)
    deflections = {}
    stiffness_rows = STIFFNESS_TEST if args.controller == "muscle_eq" else ()  # the compliant controller's test
    if stiffness_rows:
        print("\nstiffness: a tip-load step on the held joint (compliant controller)\n")
        print("| held at [deg] | stiffness [N m/deg] | load step [N] | deflection [deg] | load torque / stiffness [deg] | error |")
        print("|---|---|---|---|---|---|")
    for angle, stiffness, load in stiffness_rows:
        moved, predicted, trace = stiffness_case(args.controller, angle, stiffness, load)
        error = (moved - predicted) / predicted
        misses += abs(error) > 0.1
        deflections[(angle, stiffness, load)] = trace
        print(f"| {angle:g} | {stiffness:g} | {load:g} | {moved:.2f} | {predicted:.2f} | {error * 100:+.1f} % |", flush=True)
    if args.plot:
        for path in figures(traces, deflections, Path(args.plot), args.controller):
            print(f"wrote {path}")
    print(f"\n{misses} case(s) outside the goal")
    return 0


if __name__ == "__main__":
    sys.exit(main())
