"""One evaluation case: a controller on a plant over a reference, through the daemon's own loop
on a virtual clock (the cycle, the supervisor, the clamps, the simulated rig's sensors and
noise: what the arm would see from the daemon), with the plant's step compiled
(:mod:`sim_backend.compiled_plant`, reached by the transport's name and options like any
simulated rig). Faster than real time; deterministic.

The protocol (as bench/robustness.py had it): enable at rest, approach the reference's start in
the shortest feasible time (at least 3 s) and settle there 5 s, run it, hold its end 8 s. The
supervisor's tracking rule is off: the controller is what is measured, and a rule that stops a
weak plant's run would hide how far it goes; every other trip (limits, speed, a controller
that raised or returned a non-finite output) ends the case with the supervisor's cause.

Figures per case: tip error [mm] (distance between the tips the reference and the measured
angles put by forward kinematics [2-9..2-14]) max and RMS, joint error [deg] max and RMS, over
the reference and 2 s after; output activity (sum |du| per second, worst joint) [V/s] and
saturation (share of cycles at a limit, worst joint) [%] while it runs; sign changes per
second of the output in the last 3 s of the hold (+-0.1 V hysteresis: the regulator's
+-1 % F.S. linearity); settling: the time after the reference's end until every joint stays
within 0.5 deg [s] (NaN: not within the hold); the worst joint error at the hold's end [deg].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from controllers import lti_design, registry, trajectory
from daemon import assembly
from daemon.evaluation import cases
from daemon.loop.clock import VirtualClock
from daemon.loop.cycle import ControlLoop
from hal import config, kinematics

SETTLE_S = 5.0  # held at the reference's start before it runs [s]
TAIL_S = 2.0  # tracking measured after the reference's end [s]
HOLD_S = 8.0  # observed after the reference's end [s]; the last 3 s are the steady state
BAND_DEG = 0.5  # settled: every joint within this of its reference [deg]
RECOVER_S = 5.0  # ... within this long after the end: "recovered" [s]
HYSTERESIS_V = 0.1
TRACE_EVERY = 10  # cycles between the samples kept for figures


@dataclass
class Case:
    controller: str
    plant: str
    reference: str
    duration_s: float
    tip_max_mm: float = math.nan
    tip_rms_mm: float = math.nan
    joint_max_deg: float = math.nan
    joint_rms_deg: float = math.nan
    at_limit_pct: float = math.nan
    motion_v_s: float = math.nan
    sign_changes_per_s: float = math.nan
    settle_s: float = math.nan
    recovered: bool = False
    final_deg: float = math.nan
    tripped: str = ""
    trace: dict = field(default_factory=dict, repr=False)  # t [s], joint errors [deg], outputs [V]: for figures


def construction_options(controller: str) -> dict | None:
    """What a built-in needs to be built: the LTI ones the shipped example design
    (controllers/designs/pi_thesis.toml); the others none."""
    return {"design": lti_design.read_file(lti_design.EXAMPLE)} if controller in ("lti", "lti_dob") else None


def evaluation_rig(rig: config.RigConfig, plant: cases.Plant, compiled: bool = True) -> config.RigConfig:
    """The rig with ``plant``'s true plant behind its simulator (compiled step) and the
    tracking rule off."""
    options = {**rig.transport.options, **plant.sim_options(rig), "compiled": compiled}
    changed = config.with_transport(rig, "sim", options)
    return replace(changed, safety=replace(changed.safety, tracking_error_deg=0.0))


def make_loop(rig: config.RigConfig, controller: str, params: dict | None, options: dict | None,
              plugins: dict[str, str] | None = None) -> ControlLoop:
    """An enabled loop on ``rig`` on a fresh virtual clock with ``controller`` active."""
    loop = assembly.build_loop(rig, VirtualClock(), 0.001, "hold", plugins, contact=False)
    loop.start()
    loop.switch(registry.build(controller, loop.context, params, options, plugins))
    loop.enable()
    return loop


def approach_duration(loop: ControlLoop, target) -> float:
    """The shortest feasible time (at least 3 s) from the present reference to ``target`` [s]."""
    move = trajectory.JointMove(list(loop.reference[0]), target, 3.0)
    shortest = cases.authority(loop.rig, loop.context).shortest(move)
    return 30.0 if shortest is None else max(3.0, math.ceil(shortest * 10.0) / 10.0)


def run_case(rig: config.RigConfig, controller: str, plant: cases.Plant, name: str, path: trajectory.Trajectory,
             params: dict | None = None, options: dict | None = None, plugins: dict[str, str] | None = None,
             compiled: bool = True, trace: bool = False) -> Case:
    """One case (module docstring); ``trace`` keeps every TRACE_EVERY-th cycle for figures."""
    loop = make_loop(evaluation_rig(rig, plant, compiled), controller, params, options, plugins)
    case = Case(controller, plant.name, name, path.duration)
    start = path.sample(0.0)[0]
    move = trajectory.JointMove(list(loop.reference[0]), start, approach_duration(loop, start))
    loop.set_trajectory(move, "approach")
    loop.run(int((move.duration + SETTLE_S) / loop.period))
    if loop.state.value != "enabled":
        case.tripped = f"before the reference: {loop.supervisor.cause}"
        return case
    loop.set_trajectory(path, "path")
    measure(loop, path, case, trace)
    return case


def measure(loop: ControlLoop, path: trajectory.Trajectory, case: Case, trace: bool) -> None:
    """Run ``path`` from where the loop is, then the hold, and fill ``case``'s figures."""
    lengths, n, dt = loop.rig.arm.link_lengths_m, loop.n, loop.period
    lo, hi = loop.context.u_min, loop.context.u_max
    moving, tracked, after = round(path.duration / dt), round((path.duration + TAIL_S) / dt), round(HOLD_S / dt)
    steady = moving + after - round(3.0 / dt)
    tip_sq = tip_max = 0.0
    joint_sq, joint_max = [0.0] * n, [0.0] * n
    at_limit, motion = [0] * n, [0.0] * n
    last_u, side, flips, last_out = list(loop.u), [0] * n, 0, 0
    kept = {"t": [], "error_deg": [], "u": []} if trace else None
    worst = 0.0
    for i in range(moving + after):
        loop.run(1)
        if loop.state.value != "enabled":
            case.tripped = loop.supervisor.cause
            break
        ref, q, u = loop.reference[0], loop.angles, loop.u
        errors = [math.degrees(r - a) for r, a in zip(ref, q)]
        worst = max(abs(e) for e in errors)
        if kept is not None and i % TRACE_EVERY == 0:
            kept["t"].append(i * dt)
            kept["error_deg"].append(errors)
            kept["u"].append(list(u))
        if i < tracked:
            rx, ry = kinematics.forward(ref[:2], lengths[:2])
            mx, my = kinematics.forward(q[:2], lengths[:2])
            d = math.hypot(rx - mx, ry - my) * 1e3
            tip_sq += d * d
            tip_max = max(tip_max, d)
            for j, e in enumerate(errors):
                joint_sq[j] += e * e
                joint_max[j] = max(joint_max[j], abs(e))
        if i < moving:
            for j in range(n):
                at_limit[j] += u[j] <= lo[j] or u[j] >= hi[j]
                motion[j] += abs(u[j] - last_u[j])
        elif worst >= BAND_DEG:
            last_out = i - moving + 1  # the last cycle after the end still outside the band
        if i >= steady:
            for j in range(n):
                s = 1 if u[j] > HYSTERESIS_V else -1 if u[j] < -HYSTERESIS_V else side[j]
                flips += s != side[j] and side[j] != 0
                side[j] = s
        last_u = list(u)
    if kept is not None:
        case.trace = kept
    if case.tripped:
        return
    case.tip_max_mm, case.tip_rms_mm = tip_max, math.sqrt(tip_sq / tracked)
    case.joint_max_deg, case.joint_rms_deg = max(joint_max), max(math.sqrt(s / tracked) for s in joint_sq)
    case.at_limit_pct = 100.0 * max(at_limit) / max(moving, 1)
    case.motion_v_s = max(motion) / path.duration
    case.sign_changes_per_s = flips / 3.0
    settled = worst < BAND_DEG and last_out < after
    case.settle_s = last_out * dt if settled else math.nan
    case.recovered = settled and last_out * dt <= RECOVER_S
    case.final_deg = worst
