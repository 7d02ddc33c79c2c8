"""The thesis PID's 10 deg steps on the simulated rig under each friction model (issue 32).

    python -m bench.friction_steps [--plot docs/images] [--seconds 40]

The default friction is [2-45] as identified: the smooth-sign Stribeck map with the thesis's
beta (``friction_model = "stribeck"``); Karnopp's exact stiction is the rig-file option for
stick-slip studies (``[transport.options] friction_model = "karnopp"``). Each joint's step runs
read -> PID (the thesis's gains, rig-facts §1 [3-3, 3-4]) -> write in lockstep on a virtual
clock (daemon.testing.simrig). Printed per joint and model: overshoot and 5 % settling time,
and the late band: the largest |angle - set-point| after SETTLED_AFTER_S, which is where
Karnopp's stiction makes PI hunt and the identified map lets it settle.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from bench.common import header
from bench.scenarios import step_metrics
from controllers.pid import PID
from daemon.testing.simrig import closed_loop, make_rig

STEP_AT = 1.0  # [s]
STEP_DEG = 10.0
SETTLED_AFTER_S = 15.0  # the late band is measured this long after the step [s]
MODELS = ("stribeck", "karnopp")
JOINTS = ("bottom", "middle")


def step(joint: int, model: str, seconds: float, rig: str = "sim"):
    """Times [s] and the joint's angle change [deg] for a 10 deg step at STEP_AT."""
    sim = make_rig(f'friction_model = "{model}"', name=rig)
    q0 = list(sim.io.read().angles)

    def reference(t):
        q = list(q0)
        if t >= STEP_AT:
            q[joint] += math.radians(STEP_DEG)
        return q

    t, angles, _ = closed_loop(sim, PID(sim.context()), reference, seconds)
    return t, [math.degrees(a[joint] - q0[joint]) for a in angles]


def metrics(t, y) -> dict:
    after = [(ti - STEP_AT, yi) for ti, yi in zip(t, y) if ti >= STEP_AT]
    result = step_metrics([a for a, _ in after], [b for _, b in after], STEP_DEG)
    late = [abs(b - STEP_DEG) for a, b in after if a >= SETTLED_AFTER_S]
    return {"overshoot": result.overshoot, "settling": result.settling, "late": max(late) if late else math.nan}


def plot(runs: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(JOINTS), figsize=(11, 4), constrained_layout=True)
    for ax, joint in zip(axes, JOINTS):
        for model, style in zip(MODELS, ("-", "--")):
            t, y = runs[joint, model]
            label = {"stribeck": "smooth sign [2-45] (default)", "karnopp": "Karnopp stiction (option)"}[model]
            ax.plot(t, y, style, label=label)
        ax.axhline(STEP_DEG, color="grey", lw=0.8)
        ax.axhspan(STEP_DEG * 0.95, STEP_DEG * 1.05, color="grey", alpha=0.15, label="5 % band")
        ax.set_title(f"{joint} joint: thesis PID, {STEP_DEG:g} deg step at t = {STEP_AT:g} s")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("angle change [deg]")
        ax.legend(loc="lower right")
        ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.friction_steps", description=__doc__.splitlines()[0])
    ap.add_argument("--plot", default=None, help="a folder to write friction-steps.png into")
    ap.add_argument("--seconds", type=float, default=40.0)
    args = ap.parse_args(argv)
    header("the thesis PID's 10 deg steps under each friction model (simulated rig)")
    runs = {}
    print(f"{'joint':8s} {'friction':10s} {'overshoot':>10s} {'settling 5 %':>13s} {'late band':>10s}")
    for joint_index, joint in enumerate(JOINTS):
        for model in MODELS:
            runs[joint, model] = step(joint_index, model, args.seconds)
            m = metrics(*runs[joint, model])
            print(f"{joint:8s} {model:10s} {m['overshoot']:9.1f}% {m['settling']:12.2f}s {m['late']:9.2f}deg")
    if args.plot:
        path = Path(args.plot) / "friction-steps.png"
        plot(runs, path)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
