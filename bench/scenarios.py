"""Controller scenarios on the simulated rig, run through the real control loop on a virtual
clock: the reference paths, a step and a step disturbance torque. Shared by the comparison
table (bench/compare_controllers.py) and the acceptance tests.

Figures: joint error [deg] = reference - measured angle; tip error [mm] = distance between
the tips the reference and the measured angles put by forward kinematics [2-9..2-14].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from controllers import lti_design, registry, trajectory
from controllers.feasibility import Authority
from daemon.loop.cycle import ControlLoop
from daemon.testing.loop import virtual_loop
from hal import config, kinematics

NO_TRACKING_RULE = {"tracking_error_deg = 10.0": "tracking_error_deg = 0.0"}  # a make_loop ``replace``
SETTLE_S = 5.0  # hold at the path's start before it runs [s]
TAIL_S = 2.0  # measured after the path ends [s]


def make_loop(controller: str, params: dict | None = None, rig: str = "sim", replace: dict | None = None,
              options: dict | None = None, plant: dict | None = None) -> ControlLoop:
    """An enabled loop on the built-in simulated rig with the named controller active.
    ``plant`` is merged into the simulator's ``[transport.options]`` (e.g. a joint's
    ``overrides``, ``adc_noise_volts``): the true plant changes, the controllers' nominal
    models (the rig's ``[[joints]] model``) do not."""
    text = config.load(rig).source
    for old, new in (replace or {}).items():
        text = text.replace(old, new)
    cfg = config.parse(text, f"builtin:{rig}")
    if plant:
        cfg = config.with_transport(cfg, cfg.transport.backend, {**cfg.transport.options, **plant})
    loop = virtual_loop(cfg, "hold")
    loop.start()
    loop.switch(registry.build(controller, loop.context, params, options))
    loop.enable()
    return loop


def example_options(controller: str) -> dict | None:
    """Construction options the benches give a controller: the LTI ones run the shipped
    example design (controllers/designs/pi_thesis.toml), the others need none."""
    return {"design": lti_design.read_file(lti_design.EXAMPLE)} if controller.startswith("lti") else None


def authority(loop: ControlLoop) -> Authority:
    return Authority.of(loop.rig, loop.context, loop.rig.limits.authority_fraction)


@dataclass
class Tracking:
    joint_max: list[float] = field(default_factory=list)  # [deg]
    joint_rms: list[float] = field(default_factory=list)
    tip_max: float = 0.0  # [mm]
    tip_rms: float = 0.0
    duration: float = 0.0  # of the path [s]
    cycles: int = 0
    max_jump: list[float] = field(default_factory=list)  # largest output change in one cycle [V]


def approach_duration(loop: ControlLoop, target) -> float:
    """The shortest feasible time (at least 3 s) to move from the present reference to
    ``target`` [s]: planning, so it takes a while; a real-time loop must not wait on it."""
    shortest = authority(loop).shortest(trajectory.JointMove(list(loop.reference[0]), target, 3.0))
    return 30.0 if shortest is None else max(3.0, math.ceil(shortest * 10.0) / 10.0)


def approach(loop: ControlLoop, target, duration: float | None = None) -> None:
    """Move to ``target`` in ``duration`` (default: the shortest feasible), then settle there."""
    move = trajectory.JointMove(list(loop.reference[0]), target, duration or approach_duration(loop, target))
    loop.set_trajectory(move, "approach")
    loop.run(int((move.duration + SETTLE_S) / loop.period))


def run_path(loop: ControlLoop, path: trajectory.Trajectory, on_cycle=None) -> Tracking:
    """Approach the path's start, run it, and measure the tracking while it runs."""
    approach(loop, path.sample(0.0)[0])
    return measure_path(loop, path, on_cycle)


def measure_path(loop: ControlLoop, path: trajectory.Trajectory, on_cycle=None) -> Tracking:
    """Run the path from where the loop is and measure the tracking while it runs."""
    loop.set_trajectory(path, "path")
    lengths = loop.rig.arm.link_lengths_m
    n = loop.n
    sq, worst, tip_sq, tip_worst, jumps = [0.0] * n, [0.0] * n, 0.0, 0.0, [0.0] * n
    cycles = int((path.duration + TAIL_S) / loop.period)
    last_u = list(loop.u)
    for i in range(cycles):
        if on_cycle is not None:
            on_cycle(loop, i)
        loop.run(1)
        ref, q = loop.reference[0], loop.angles
        for j in range(n):
            e = math.degrees(ref[j] - q[j])
            sq[j] += e * e
            worst[j] = max(worst[j], abs(e))
            jumps[j] = max(jumps[j], abs(loop.u[j] - last_u[j]))
        last_u = list(loop.u)
        rx, ry = kinematics.forward(ref[:2], lengths[:2])
        mx, my = kinematics.forward(q[:2], lengths[:2])
        d = math.hypot(rx - mx, ry - my) * 1e3
        tip_sq += d * d
        tip_worst = max(tip_worst, d)
    return Tracking(worst, [math.sqrt(s / cycles) for s in sq], tip_worst, math.sqrt(tip_sq / cycles),
                    path.duration, cycles, jumps)


def make_path(loop: ControlLoop, name: str, duration: float) -> trajectory.Trajectory:
    make = {"translation": trajectory.translation, "circle": trajectory.circle}[name]
    return make(loop.rig.arm.link_lengths_m, loop.rig.arm.elbow, loop.n, duration)


def shortest_feasible(loop: ControlLoop, name: str, fraction: float = 1.0) -> float:
    """The shortest duration of a reference path [s] with ``fraction`` of V_MV's range: by
    default the whole of it, the rig's physical limit the lab comparison runs at (the
    daemon accepts only what its rig file's ``limits.authority_fraction`` leaves)."""
    full = Authority.of(loop.rig, loop.context, fraction)
    return math.ceil(full.shortest(make_path(loop, name, 1.0)) * 10.0) / 10.0


@dataclass
class StepResult:
    rise: float  # 10-90 % [s]
    overshoot: float  # [% of the step]
    settling: float  # into +-5 % of the step, for good [s]


def step_response(loop: ControlLoop, joint: int, step_deg: float, seconds: float) -> StepResult:
    """A set-point step on one joint from rest; the others hold."""
    loop.hold()
    loop.run(int(SETTLE_S / loop.period))
    q0 = list(loop.reference[0])
    target = list(q0)
    target[joint] += math.radians(step_deg)
    loop.set_trajectory(trajectory.JointMove(q0, target, 0.0), "step")
    t, y = [], []
    for i in range(int(seconds / loop.period)):
        loop.run(1)
        t.append(i * loop.period)
        y.append(math.degrees(loop.angles[joint] - q0[joint]))
    return step_metrics(t, y, step_deg)


def step_metrics(t, y, step) -> StepResult:
    """Rise, overshoot and settling of a response y(t) to a step of ``step`` at t = 0."""
    sign = 1.0 if step > 0 else -1.0
    rel = [sign * v / abs(step) for v in y]
    t10 = next((ti for ti, v in zip(t, rel) if v >= 0.1), math.nan)
    t90 = next((ti for ti, v in zip(t, rel) if v >= 0.9), math.nan)
    settle = 0.0
    for ti, v in zip(t, rel):
        if abs(v - 1.0) > 0.05:
            settle = ti
    return StepResult(t90 - t10, max(0.0, (max(rel) - 1.0) * 100.0), settle)


@dataclass
class Rejection:
    peak: float  # largest deviation [deg]
    recovery: float  # back within 0.5 deg for good [s]


def disturbance_rejection(loop: ControlLoop, joint: int, torque_nm: float, seconds: float) -> Rejection:
    """A step torque [N m] on one joint while it holds position."""
    loop.hold()
    loop.run(int(SETTLE_S / loop.period))
    q0 = loop.reference[0][joint]
    loop.io.transport.arm.disturbance_nm[joint] = torque_nm
    peak, recovery = 0.0, 0.0
    for i in range(int(seconds / loop.period)):
        loop.run(1)
        dev = abs(math.degrees(loop.angles[joint] - q0))
        peak = max(peak, dev)
        if dev > 0.5:
            recovery = (i + 1) * loop.period
    loop.io.transport.arm.disturbance_nm[joint] = 0.0
    return Rejection(peak, recovery)
