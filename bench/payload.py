"""Payload identification on the simulated arm (rig-facts §4), and the paper's noise study.

    python -m bench.payload [--repeats 3] [--noise-runs 10] [--noise-only] [--plot docs/images/payload-noise.png]

The arm: the built-in rig, in a vertical plane (``arm.gravity_m_s2``), with its sensor noise
and friction. **Capacity** (this arm's, for scaling the paper's figures): the middle joint decides it. Of
its V_MV range (-3.2..4.8 V at 0.133 N m/V) the routine's postures leave up to 0.75 V to its
spring and the dither takes 2.2 V; what remains on the side the payload pulls, about 1.8 V or
0.24 N m, holds about 0.2 kg at its largest moment arm (its link, 100 mm): 0.2 kg. The
paper's arm carried up to 2.963 kg (say 3 kg) over about 0.5 m of reach; its 0.032 kg and
4.14 mm scale to this arm as mass x (0.2 / 3) and length x (0.2 / 0.5).

Each payload runs the routine of ``pneumactl payload identify`` (daemon.client.payload_routine)
through the real loop on a virtual clock: postures, each joint dithered there, its balance
torque from the pressure commands, against an unloaded reference run first. The noise study
repeats the paper's (rig-facts §4): the torque differences at the same postures, exact, with
Gaussian noise of 1-20 % of each, ``--noise-runs`` times: the RMS error of each estimate.
"""
from __future__ import annotations

import argparse
import math
from importlib import resources

import numpy as np

from bench.common import header
from controllers.payload import Posture, identify
from daemon.client import payload_routine
from hal import config
from hal.kinematics import payload_torques

CAPACITY_KG = 0.2
PAPER = {"mass_kg": 0.032, "com_mm": 4.14, "capacity_kg": 3.0, "reach_m": 0.5}
PAYLOADS = [(0.05, (10.0, 0.0)), (0.1, (20.0, -10.0)), (0.15, (-10.0, 15.0)), (0.2, (30.0, 5.0))]
NOISE_LEVELS = (0.01, 0.05, 0.10, 0.20)
PAPER_NOISE = {0.01: (2.75, 3.14, 0.013), 0.05: (3.33, 3.54, 0.043), 0.10: (4.45, 4.32, 0.073),
               0.20: (9.75, 6.58, 0.130)}  # rig-facts §4: x, y [mm], mass [kg] (its z: our out-of-plane)


def rig_text(mass_kg: float, com_mm: tuple[float, float]) -> str:
    text = resources.files("hal").joinpath("sim_2joint.toml").read_text()
    return text + f"\n[transport.options.payload]\nmass_kg = {mass_kg}\ncom_mm = [{com_mm[0]}, {com_mm[1]}]\n"


def loop_arm(loop, sock, lease, run_seconds, ok, call):
    """The routine's Arm on an in-process loop (virtual clock)."""
    def advance(seconds: float) -> None:  # the lease counts virtual seconds: renewed as they pass
        while seconds > 0:
            run_seconds(loop, min(seconds, 10.0))
            seconds -= 10.0
            ok(loop, sock, "lease.renew", lease=lease)

    def move(target: list[float]) -> None:
        here = [math.degrees(a) for a in loop.reference[0]]
        duration = max(1.5, max(abs(a - b) for a, b in zip(target, here)) / 20.0)
        ok(loop, sock, "lease.renew", lease=lease)
        reply = call(loop, sock, "set", {"angles_deg": target, "duration_s": duration}, lease)
        if not reply["ok"] and (reply["error"].get("data") or {}).get("shortest_s"):  # slower, as the daemon says
            duration = 1.1 * reply["error"]["data"]["shortest_s"]
            reply = ok(loop, sock, "set", {"angles_deg": target, "duration_s": duration}, lease)
        else:
            assert reply["ok"], reply
            reply = reply["result"]
        advance(reply["duration_s"])
        window = []
        for _ in range(200):  # at rest: within 0.3 deg of the target, still, for 0.5 s
            run_seconds(loop, 0.05)
            window = (window + [[math.degrees(a) for a in loop.angles]])[-10:]
            if len(window) == 10 and all(max(c) - min(c) < 0.05 and abs(c[-1] - t) < 0.3
                                         for c, t in zip(zip(*window), target)):
                return

    def dithered(joint: str, seconds: float) -> tuple[float, float]:
        j = [jc.name for jc in loop.rig.joints].index(joint)
        reply = ok(loop, sock, "excite", payload_routine.dither_args(loop.rig, joint), lease)
        advance(payload_routine.sampling_starts_s(reply["duration_s"], seconds))
        rows = []
        while not rows or rows[-1][0] > payload_routine.END_GUARD_S:  # by the dither's clock, as a client
            run_seconds(loop, 0.01)
            rows.append((loop.reference_remaining(), loop.u[j], math.degrees(loop.angles[j])))
        ok(loop, sock, "lease.renew", lease=lease)
        run_seconds(loop, payload_routine.END_GUARD_S + 0.1)  # the dither's end
        return tuple(float(v) for v in payload_routine.window_mean(rows, seconds, joint))

    return payload_routine.Arm(move, dithered)


def measure(text: str, targets: list[list[float]]) -> list[payload_routine.Reading]:
    from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds  # the in-process daemon
    loop, _, srv = make_loop(text, server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        run_seconds(loop, 2.0)
        return payload_routine.measure(loop_arm(loop, sock, lease, run_seconds, ok, call), loop.rig, targets)
    finally:
        srv.close()


def noise_study(rig, targets, runs: int) -> list[tuple]:
    mass, com = PAYLOADS[1]
    com_m = tuple(c * 1e-3 for c in com)
    lengths, gravity = rig.arm.link_lengths_m, rig.arm.gravity_m_s2
    rng = np.random.default_rng(0)
    rows = []
    for level in NOISE_LEVELS:
        errors = []
        for _ in range(runs):
            postures = []
            for q in targets:
                q_rad = tuple(math.radians(a) for a in q)
                exact = payload_torques(q_rad, lengths, mass, com_m, gravity)
                postures.append(Posture(q_rad, tuple(t * (1 + rng.normal(0.0, level)) for t in exact)))
            found = identify(postures, lengths, gravity)
            errors.append([(found.com_m[0] - com_m[0]) * 1e3, (found.com_m[1] - com_m[1]) * 1e3,
                           found.mass_kg - mass])
        rms = np.sqrt(np.mean(np.square(errors), axis=0))
        rows.append((level, *rms))
    return rows


def scale_note(scale_l: float, scale_m: float, reach_m: float) -> str:
    """Why the paper's figures are scaled, and by what: the caption the figure carries."""
    return (f"The paper's errors (dashed) are scaled to this arm: lengths by reach, {reach_m:.2f} m / "
            f"{PAPER['reach_m']:.2f} m = x{scale_l:.2f}; mass by capacity, {CAPACITY_KG:g} kg / "
            f"{PAPER['capacity_kg']:g} kg = x{scale_m:.3f}\n(an arm this size and strength carries and places "
            f"proportionally less: bench/payload.py, docs/estimation.md)")


def plot(path: str, rows: list[tuple], scale_l: float, scale_m: float, reach_m: float) -> None:
    """Write :func:`figure` to ``path``."""
    import matplotlib.pyplot as plt
    fig = figure(rows, scale_l, scale_m, reach_m)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure(rows: list[tuple], scale_l: float, scale_m: float, reach_m: float):
    """The noise study against the paper's, the paper's figures scaled to this arm, saying why."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    levels = [r[0] * 100 for r in rows]
    fig, (ax_c, ax_m) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (name, style) in enumerate((("x (along the link)", "C0"), ("y (across)", "C1"))):
        ax_c.plot(levels, [r[1 + k] for r in rows], style + "o-", label=f"{name}, this arm")
        ax_c.plot(levels, [PAPER_NOISE[r[0]][k] * scale_l for r in rows], style + "s--", alpha=0.6,
                  label=f"{name}, the paper's x{scale_l:.2f} (reach ratio)")
    ax_m.plot(levels, [r[3] * 1e3 for r in rows], "C2o-", label="this arm")
    ax_m.plot(levels, [PAPER_NOISE[r[0]][2] * scale_m * 1e3 for r in rows], "C2s--", alpha=0.6,
              label=f"the paper's x{scale_m:.3f} (capacity ratio)")
    ax_c.set_ylabel("centre of mass RMS error [mm]")
    ax_m.set_ylabel("mass RMS error [g]")
    for ax in (ax_c, ax_m):
        ax.set_xlabel("torque noise [% of each torque]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Payload identification: error against torque noise (bench.payload; z is not identifiable here)")
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.text(0.01, 0.01, scale_note(scale_l, scale_m, reach_m), fontsize=9, va="bottom")
    return fig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.payload", description=__doc__.splitlines()[0])
    ap.add_argument("--noise-runs", type=int, default=10)
    ap.add_argument("--noise-only", action="store_true", help="the noise study alone (no runs on the arm)")
    ap.add_argument("--repeats", type=int, default=3, help="rounds of the routine on the arm (default 3)")
    ap.add_argument("--plot", default=None, help="write the noise study as a PNG")
    args = ap.parse_args(argv)
    header("payload identification by torque balance on the simulated arm")
    rig = config.load()
    targets = payload_routine.postures(rig)
    scale_m = CAPACITY_KG / PAPER["capacity_kg"]
    scale_l = sum(rig.arm.link_lengths_m) / PAPER["reach_m"]
    goal_mass, goal_com = PAPER["mass_kg"] * scale_m, PAPER["com_mm"] * scale_l
    print(f"postures [deg]: {targets}")
    print(f"goal (the paper's, scaled): mass within {goal_mass * 1e3:.1f} g, centre of mass within {goal_com:.2f} mm")
    if not args.noise_only:
        arm_table(rig, targets, args.repeats)
    print(f"\nnoise study ({args.noise_runs} runs a level, payload {PAYLOADS[1][0]} kg at {PAYLOADS[1][1]} mm; "
          "RMS error; z: out of the arm's plane)\n")
    print("| torque noise | x (along) mm | y (across) mm | z mm | mass kg |")
    print("|---|---|---|---|---|")
    rows = noise_study(rig, targets, args.noise_runs)
    for level, ex, ey, em in rows:
        print(f"| {level:.0%} | {ex:.2f} | {ey:.2f} | not identifiable | {em:.4f} |")
    if args.plot:
        plot(args.plot, rows, scale_l, scale_m, sum(rig.arm.link_lengths_m))
        print(f"wrote {args.plot}")
    return 0


def arm_table(rig, targets, repeats: int) -> None:
    """The routine on the simulated arm: ``repeats`` rounds, each an unloaded reference and
    every payload against it (the loop's virtual time drifts with how long the planner takes,
    so no two rounds meet friction alike); each payload's mean estimate, and its largest
    errors over the rounds."""
    found = {payload: [] for payload in PAYLOADS}
    for _ in range(repeats):
        unloaded = measure(rig_text(0.0, (0.0, 0.0)), targets)
        for mass, com in PAYLOADS:
            found[(mass, com)].append(payload_routine.estimate(rig, unloaded, measure(rig_text(mass, com), targets)))
    print(f"\n{repeats} round(s), each an unloaded reference and every payload against it; "
          "mean estimate, its 1 sigma (the routine's own, mean), and the largest errors over the rounds\n")
    print("| payload [kg] | centre of mass (along, across) [mm] | mass found [kg] | mass errors [g] | "
          "centre found [mm] | centre errors [mm] | out of plane |")
    print("|---|---|---|---|---|---|---|")
    for (mass, com), runs in found.items():
        masses = [f.mass_kg for f in runs]
        mass_errors = [(m - mass) * 1e3 for m in masses]
        misses = [math.hypot(f.com_m[0] * 1e3 - com[0], f.com_m[1] * 1e3 - com[1]) for f in runs]
        centre = np.mean([f.com_m for f in runs], axis=0) * 1e3
        print(f"| {mass:.2f} | {com[0]:.0f}, {com[1]:.0f} | {np.mean(masses):.4f} +- "
              f"{np.mean([f.mass_std_kg for f in runs]):.4f} | {', '.join(f'{e:+.1f}' for e in mass_errors)} "
              f"(worst {max(map(abs, mass_errors)):.1f}) | {centre[0]:.1f}, {centre[1]:.1f} | "
              f"{', '.join(f'{d:.1f}' for d in misses)} (worst {max(misses):.1f}) | not identifiable |")


if __name__ == "__main__":
    raise SystemExit(main())
