"""Every built-in controller at the rig's edges: the reference paths and unseen ones, on the
nominal plant and on the corners of the thesis's uncertainty set, with the rig's sensor noise.

Through the real loop on a virtual clock (bench/scenarios.py). The true plant changes (the
simulator's per-joint ``overrides``); the controllers keep their nominal models. The
uncertainty set (rig-facts §1 "Robust-control view" and the issue's ranges): plant gain
K_mdl x0.41..x1.41 per joint, friction and viscous terms (Fs, Fc, D) x0.7..x1.5, dead time
T_dly x0.8..x1.2. Its 16 corners are run, plus the nominal plant with and without noise.

Per case: tip max / RMS [mm] and joint max [deg] while the path runs (and 2 s after), the
share of the path's cycles a joint's output sits at a limit [%], output motion (sum |du| per
second, worst joint) [V/s], the output's sign changes per second in the hold after (counted
with a +-0.1 V hysteresis: the regulator's +-1 % F.S. linearity, below which a sign is not
physical), whether every joint was back within 0.5 deg within 5 s of the path's end and
stayed there, and whether the arm tripped (the supervisor's tracking rule is off here: it
would stop the runs on the weak plants, where the controllers are what is measured).

    python -m bench.robustness [--controllers pid smc] [--quick] [--csv docs/robustness.csv]
"""
from __future__ import annotations

import argparse
import csv
import itertools
import math
import multiprocessing
import sys
import time
from dataclasses import asdict, dataclass

from bench import scenarios as S
from controllers import trajectory
from hal import config, kinematics

CONTROLLERS = ["pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]
JOINTS = ("bottom", "middle")


def nominal_params() -> dict:
    """The built-in rig's model per joint (what the factors below multiply): the rig's own
    model sets, so a rig whose models change (issue 32) is perturbed about its own values."""
    rig = config.load()
    return {j.name: rig.joint_params(j) for j in rig.joints}


RECOVER_S, RECOVER_DEG = 5.0, 0.5  # back within 0.5 deg within 5 s of the path's end
HOLD_S = 8.0  # observed after the path's end [s]; the last 3 s are the steady state
HYSTERESIS_V = 0.1


@dataclass(frozen=True)
class Plant:
    name: str
    gain: tuple[float, float] = (1.0, 1.0)  # K_mdl factor per joint
    friction: float = 1.0  # Fs, Fc factor
    delay: float = 1.0  # T_dly factor
    noise: bool = True
    damping: float | None = None  # D factor; None: the friction factor (Fs, Fc and D together)

    def sim_options(self) -> dict:
        joints, nominal = {}, nominal_params()
        damping = self.friction if self.damping is None else self.damping
        for j, name in enumerate(JOINTS):
            n = nominal[name]
            joints[name] = {"overrides": {"K_mdl": n.K_mdl * self.gain[j], "Fs": n.Fs * self.friction,
                                          "Fc": n.Fc * self.friction, "D": n.D * damping,
                                          "T_dly": n.T_dly * self.delay}}
        return {"joints": joints, **({} if self.noise else {"adc_noise_volts": 0.0})}


def plants(quick: bool = False) -> list[Plant]:
    """The nominal plant without and with noise, then the corners of the uncertainty set."""
    out = [Plant("nominal, no noise", noise=False), Plant("nominal")]
    gains = [(0.41, 0.41), (1.41, 1.41)] if quick else list(itertools.product((0.41, 1.41), repeat=2))
    for g, f, d in itertools.product(gains, (0.7, 1.5), (0.8, 1.2)):
        out.append(Plant(f"gain {g[0]:g}/{g[1]:g}, friction x{f:g}, delay x{d:g}", g, f, d))
    return out


SQUARE_MM = [(20.0, 125.0), (40.0, 125.0), (40.0, 145.0), (20.0, 145.0), (20.0, 125.0)]  # 20 mm sides about (30, 135)


def shapes(loop, scale: float = 1.0) -> dict[str, trajectory.Trajectory]:
    """The paths at duration ``scale`` (scaled to the fastest the rig accepts in :func:`paths`)."""
    lengths, elbow, n = loop.rig.arm.link_lengths_m, loop.rig.arm.elbow, loop.n
    return {"line (vertical)": trajectory.line(lengths, elbow, n, 10.0 * scale, (30.0, 110.0), (30.0, 160.0)),
            "figure-eight": trajectory.figure_eight(lengths, elbow, n, 20.0 * scale, (30.0, 135.0), 20.0, 20.0),
            "square (corners)": trajectory.cartesian_waypoints(lengths, elbow, n, SQUARE_MM, [5.0 * scale] * 4)}


def paths(loop, with_circle: bool) -> dict[str, trajectory.Trajectory]:
    """The thesis's translation (15 s), its circle at the shortest feasible period when asked,
    and the unseen paths each at the fastest the rig's feasibility check accepts."""
    out = {"translation": S.make_path(loop, "translation", 15.0)}
    if with_circle:
        out["circle"] = S.make_path(loop, "circle", S.shortest_feasible(loop, "circle"))
    authority = S.authority(loop)
    for name, path in shapes(loop).items():
        fastest = math.ceil(authority.shortest(path) * 10.0) / 10.0
        out[name] = shapes(loop, fastest / path.duration)[name]
    return out


@dataclass
class Case:
    controller: str
    plant: str
    path: str
    duration_s: float
    tip_max_mm: float = math.nan
    tip_rms_mm: float = math.nan
    joint_max_deg: float = math.nan
    at_limit_pct: float = math.nan
    motion_v_s: float = math.nan
    sign_changes_per_s: float = math.nan
    recovered: bool = False
    final_deg: float = math.nan  # worst joint error at the end of the hold: a slow recovery or none
    tripped: str = ""


def run_case(controller: str, plant: Plant, name: str, path: trajectory.Trajectory) -> Case:
    loop = S.make_loop(controller, options=S.example_options(controller), plant=plant.sim_options(),
                       replace=S.NO_TRACKING_RULE)  # the controllers are measured here, not the supervisor's rule
    case = Case(controller, plant.name, name, path.duration)
    S.approach(loop, path.sample(0.0)[0])
    if loop.state.value != "enabled":
        case.tripped = f"before the path: {loop.supervisor.cause}"
        return case
    loop.set_trajectory(path, "path")
    lengths, n, dt = loop.rig.arm.link_lengths_m, loop.n, loop.period
    lo, hi = loop.context.u_min, loop.context.u_max
    tracked = int((path.duration + S.TAIL_S) / dt)
    moving, after = int(path.duration / dt), int(HOLD_S / dt)
    tip_sq = tip_max = joint_max = 0.0
    at_limit, motion = [0] * n, [0.0] * n
    last_u, side, flips, last_out = list(loop.u), [0] * n, 0, 0
    for i in range(moving + after):
        loop.run(1)
        if loop.state.value != "enabled":
            case.tripped = loop.supervisor.cause
            return case
        ref, q, u = loop.reference[0], loop.angles, loop.u
        worst = max(abs(math.degrees(r - a)) for r, a in zip(ref, q))
        if i < tracked:
            rx, ry = kinematics.forward(ref[:2], lengths[:2])
            mx, my = kinematics.forward(q[:2], lengths[:2])
            d = math.hypot(rx - mx, ry - my) * 1e3
            tip_sq += d * d
            tip_max, joint_max = max(tip_max, d), max(joint_max, worst)
        if i < moving:
            for j in range(n):
                at_limit[j] += u[j] <= lo[j] or u[j] >= hi[j]
                motion[j] += abs(u[j] - last_u[j])
        elif worst >= RECOVER_DEG:
            last_out = i - moving + 1  # the last cycle after the end still outside the band
        if i >= moving + after - int(3.0 / dt):
            for j in range(n):
                s = 1 if u[j] > HYSTERESIS_V else -1 if u[j] < -HYSTERESIS_V else side[j]
                flips += s != side[j] and side[j] != 0
                side[j] = s
        last_u = list(u)
    case.tip_max_mm, case.tip_rms_mm, case.joint_max_deg = tip_max, math.sqrt(tip_sq / tracked), joint_max
    case.at_limit_pct = 100.0 * max(at_limit) / moving
    case.motion_v_s = max(motion) / path.duration
    case.sign_changes_per_s = flips / 3.0
    case.recovered = last_out * dt <= RECOVER_S
    case.final_deg = worst
    return case


def run_plant(args) -> list[Case]:
    controller, plant, with_circle = args
    loop = S.make_loop(controller, options=S.example_options(controller))
    return [run_case(controller, plant, name, path) for name, path in paths(loop, with_circle).items()]


def summary(cases: list[Case]) -> str:
    """One row per controller and path: nominal figures, the worst over the grid, counts."""
    lines = ["| controller | path | tip max nominal (mm) | tip max worst (mm) | tip RMS worst (mm) | joint max worst (deg) "
             "| at limit nominal / worst (%) | motion noise-free / noisy / worst (V/s) | sign changes worst (1/s) "
             "| recovered | error 8 s after, worst (deg) | tripped |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    keys = sorted({(c.controller, c.path) for c in cases}, key=lambda k: (CONTROLLERS.index(k[0]), k[1]))
    for controller, path in keys:
        group = [c for c in cases if (c.controller, c.path) == (controller, path)]
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
    parser.add_argument("--controllers", nargs="*", default=CONTROLLERS, choices=CONTROLLERS)
    parser.add_argument("--quick", action="store_true", help="equal gains on both joints only (8 corners)")
    parser.add_argument("--csv", help="write every case here")
    args = parser.parse_args(argv)
    grid = plants(args.quick)
    tasks = [(c, p, p.name.startswith("nominal")) for c in args.controllers for p in grid]
    start = time.monotonic()
    with multiprocessing.Pool(multiprocessing.cpu_count()) as pool:
        cases = [case for result in pool.map(run_plant, tasks, chunksize=1) for case in result]
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(asdict(cases[0])))
            writer.writeheader()
            writer.writerows(asdict(c) for c in cases)
    print(f"Produced by: python -m bench.robustness {' '.join(sys.argv[1:] if argv is None else argv)}")
    print(f"({len(cases)} cases over {len(grid)} plants in {time.monotonic() - start:.0f} s; the circle runs on the "
          "nominal plant only)\n")
    print(summary(cases))
    failed = [c for c in cases if c.tripped or not c.recovered]
    if failed:
        print(f"\nNot bounded or not recovered ({len(failed)} cases):")
        for c in failed:
            print(f"- {c.controller}, {c.path}, {c.plant}: "
                  + (f"tripped ({c.tripped})" if c.tripped else
                     f"not back within 0.5 deg within 5 s; {c.final_deg:.2f} deg after {HOLD_S:g} s"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
