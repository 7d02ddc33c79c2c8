"""Reconstructing the simulated rig from the thesis's own experiments (issue 32).

    python -m bench.reconstruction [--seconds 30]

Rig-facts §1 leaves open the units of the identified parameters, the link lengths, the
spring's neutral angles and the bias; the thesis's experiments, which its rig ran, constrain
them: the 15 s translation and the 20 s circle ran with every controller (so their speeds are
inside the authority with the feedback margin, and their points inside the joint ranges the
strokes allow, roughly stroke / moment arm), and its PID gains settled the joints. Each
candidate interpretation is a rig (the built-in one with its models, links, neutral angles and
limits replaced); per candidate this prints the shortest translation and circle the daemon
would accept (the rig's ``limits.authority_fraction``), the thesis PID's 10 deg steps
(overshoot, 5 % settling, on the simulator: daemon.testing.simrig), the joint range each
path uses against the stroke's, and the spring's deflection at the thesis's operating point
(head 0.36 MPa, rod 0.27 MPa: rig-facts §1 "Actuation scheme"). docs/simulator.md shows the table.
"""
from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np

from bench.common import header
from bench.scenarios import step_metrics
from controllers import trajectory
from controllers.feasibility import Authority
from controllers.pid import PID
from daemon.testing.simrig import closed_loop, sim_of
from hal import config
from hal.identified import IDENTIFIED

OPERATING_PA = (0.36e6, 0.27e6)  # head, rod at the thesis's frequency-response operating point [Pa]
STEP_DEG = 10.0


@dataclasses.dataclass(frozen=True)
class Candidate:
    name: str
    models: tuple[str, str]  # the bottom and middle joints' model sets
    links_mm: tuple[float, float]
    rest_deg: tuple[float, float] | None  # neutral angles chosen so the joints rest here at the bias; None: neutral
    neutral_deg: tuple[float, float] = (120.0, -100.0)
    limits_deg: tuple[tuple[float, float], tuple[float, float]] = ((85.0, 175.0), (-160.0, -40.0))
    extra_models: tuple = ()  # (name, based_on, scale u): J, D, K per u deg, vs times u


SCALE_3 = ("middle-u3", "middle", 3.0)
MID_PATH = (138.0, -121.0)  # the middle of the angles the two paths use on 150 mm links: each candidate's best chance
CANDIDATES = (
    Candidate("degree reading, 100 mm links, th_0 -100 deg (the first built-in)", ("bottom", "middle"), (100.0, 100.0),
              None, limits_deg=((85.0, 155.0), (-120.0, -40.0))),
    Candidate("degree reading, 150 mm links, resting mid-path", ("bottom", "middle"), (150.0, 150.0), MID_PATH),
    Candidate("radian reading as printed, 150 mm links, resting mid-path", ("bottom-rad", "middle-rad"), (150.0, 150.0),
              MID_PATH),
    Candidate("degree reading, middle per 3 deg (u = 3), 150 mm links, resting mid-path", ("bottom", "middle-u3"),
              (150.0, 150.0), MID_PATH, extra_models=(SCALE_3,)),
    Candidate("degree reading, middle per 7.5 deg (u = 7.5, middle-scaled), 150 mm links: the built-in",
              ("bottom", "middle-scaled"), (150.0, 150.0), (141.8, -90.0)),
    Candidate("the built-in on 200 mm links", ("bottom", "middle-scaled"), (200.0, 200.0), (141.8, -90.0)),
)


def bias_torque(p, head_pa: float, rod_pa: float) -> float:
    """K_mdl L (A_H P_H - A_L P_L) [N m], [2-32..2-35]."""
    return p.K_mdl * p.L * (p.area_head * head_pa - p.area_rod * rod_pa)


def rig_of(c: Candidate) -> config.RigConfig:
    base = config.load()
    models = dict(base.models)
    for name, based_on, u in c.extra_models:
        p = IDENTIFIED[based_on]
        models[name] = {"based_on": based_on, "J": p.J / u, "D": p.D / u, "K": p.K / u, "vs": p.vs * u,
                        "source": f"bench.reconstruction: {based_on} per {u:g} deg"}
    known = {**IDENTIFIED, **{n: None for n in models}}
    assert all(m in known for m in c.models), c.models
    joints = []
    for j, (joint, model, limits) in enumerate(zip(base.joints, c.models, c.limits_deg)):
        neutral = c.neutral_deg[j]
        if c.rest_deg is not None:
            probe = dataclasses.replace(base, models=models)
            p = probe.joint_models[model]
            bias = joint.head.bias_volts * 0.0899e6 + 0.001e6, joint.rod.bias_volts * 0.0899e6 + 0.001e6
            neutral = c.rest_deg[j] - bias_torque(p, *bias) / p.K
        joints.append(dataclasses.replace(joint, model=model, neutral_angle_deg=round(neutral, 1),
                                          min_angle_deg=limits[0], max_angle_deg=limits[1]))
    arm = dataclasses.replace(base.arm, link_lengths_mm=c.links_mm)
    return dataclasses.replace(base, joints=tuple(joints), arm=arm, models=models)


def pid_step(rig: config.RigConfig, joint: int, seconds: float) -> dict:
    sim = sim_of(rig)
    q0 = list(sim.io.read().angles)

    def reference(t):
        q = list(q0)
        if t >= 1.0:
            q[joint] += math.radians(STEP_DEG)
        return q

    t, angles, _ = closed_loop(sim, PID(sim.context()), reference, seconds)
    after = [(ti - 1.0, math.degrees(a[joint] - q0[joint])) for ti, a in zip(t, angles) if ti >= 1.0]
    r = step_metrics([a for a, _ in after], [b for _, b in after], STEP_DEG)
    peak = max(abs(b) for _, b in after)
    return {"overshoot": r.overshoot, "settling": r.settling, "peak": peak, "start": math.degrees(q0[joint])}


def evaluate(c: Candidate, seconds: float) -> dict:
    rig = rig_of(c)
    sim = sim_of(rig)
    authority = Authority.of(rig, sim.context(), rig.limits.authority_fraction)
    lengths, elbow = rig.arm.link_lengths_m, rig.arm.elbow
    out = {"candidate": c, "rest": [math.degrees(a) for a in sim.io.read().angles]}
    for name, make, duration in (("translation", trajectory.translation, 15.0), ("circle", trajectory.circle, 20.0)):
        path = make(lengths, elbow, 2, duration)
        out[name] = authority.shortest(path)
        q = np.degrees(path.profile().q)
        out[name + "_range"] = [(float(q[:, j].min()), float(q[:, j].max())) for j in range(2)]
        out[name + "_inside"] = all(jc.min_angle_deg <= lo and hi <= jc.max_angle_deg
                                    for jc, (lo, hi) in zip(rig.joints, out[name + "_range"]))
    params = [rig.joint_params(j) for j in rig.joints]
    out["stroke_deg"] = [math.degrees(p.stroke / p.L) for p in params]
    out["operating_deflection"] = [bias_torque(p, *OPERATING_PA) / p.K for p in params]
    out["steps"] = [pid_step(rig, j, seconds) for j in range(2)]
    return out


def used(r: dict, j: int) -> float:
    spans = [r[p + "_range"][j] for p in ("translation", "circle")]
    return max(hi for _, hi in spans) - min(lo for lo, _ in spans)


def table(rows: list[dict]) -> str:
    lines = ["| candidate | shortest translation (thesis: 15 s) | shortest circle (thesis: 20 s) | "
             "PID 10 deg step, bottom | PID 10 deg step, middle | range the paths use, bottom / middle "
             "(stroke / arm: 22 / 46 deg) | spring deflection at the operating point | rest angles |",
             "|---|---|---|---|---|---|---|---|"]

    def shortest(v, limit):
        if v is None:
            return "none (an end point beyond the authority)"
        return f"{max(v, 0.0):.1f} s {'runs' if v <= limit else '**refused**'}"

    def step(s):
        settled = s["settling"] < 25.0 and s["overshoot"] < 50.0
        text = f"{s['overshoot']:.1f} %, {s['settling']:.2f} s"
        return text if settled else f"**does not settle** (peak {s['peak']:.0f} deg)"

    for r in rows:
        lines.append(
            f"| {r['candidate'].name} | {shortest(r['translation'], 15.0)} | {shortest(r['circle'], 20.0)} | "
            f"{step(r['steps'][0])} | {step(r['steps'][1])} | {used(r, 0):.0f} / {used(r, 1):.0f} deg"
            f"{'' if r['translation_inside'] and r['circle_inside'] else ' (**outside the limits**)'} | "
            f"{r['operating_deflection'][0]:.0f} / {r['operating_deflection'][1]:.0f} deg | "
            f"{r['rest'][0]:.1f} / {r['rest'][1]:.1f} deg |")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.reconstruction", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="each PID step's run [s]")
    args = ap.parse_args(argv)
    header("the simulated rig's interpretations against the thesis's experiments")
    print(table([evaluate(c, args.seconds) for c in CANDIDATES]))


if __name__ == "__main__":
    main()
