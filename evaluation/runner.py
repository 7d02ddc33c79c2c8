"""One evaluation case: a controller on a plant over a reference, on the daemon's own loop on a
virtual clock (the cycle, the supervisor, the clamps, the simulated rig's sensors and noise:
what the arm would see from the daemon), set up by the daemon's code. Two engines cycle it:
``loop``, the loop itself with the Python plant (the reference), and ``fast``, the same cycle
compiled around the controller (:mod:`evaluation.fast`, with the compiled plant of
:mod:`sim_backend.compiled_plant`), held equal to it by tests/test_evaluation.py; ``auto`` takes
the fast one where it applies. Faster than real time; deterministic.

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

import numpy as np

from controllers import lti_design, registry, trajectory
from daemon import assembly
from daemon.loop.clock import VirtualClock
from daemon.loop.cycle import ControlLoop
from evaluation import cases, fast
from hal import config
from hal.errors import ConfigError

SETTLE_S = 5.0  # held at the reference's start before it runs [s]
TAIL_S = 2.0  # tracking measured after the reference's end [s]
HOLD_S = 8.0  # observed after the reference's end [s]; the last 3 s are the steady state
BAND_DEG = 0.5  # settled: every joint within this of its reference [deg]
RECOVER_S = 5.0  # ... within this long after the end: "recovered" [s]
HYSTERESIS_V = 0.1
TRACE_EVERY = 10  # cycles between the samples kept for figures


@dataclass
class Case:
    """One case's figures (module docstring); ``tripped``: the supervisor's cause, "" if it ran."""

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
    trace: dict = field(default_factory=dict, repr=False)  # t [s], joint errors [deg]: for figures


def construction_options(controller: str) -> dict | None:
    """What a built-in needs to be built: the LTI ones the shipped example design
    (controllers/designs/pi_thesis.toml); the others none."""
    return {"design": lti_design.read_file(lti_design.EXAMPLE)} if controller in ("lti", "lti_dob") else None


def evaluation_rig(rig: config.RigConfig, plant: cases.Plant, compiled: bool) -> config.RigConfig:
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


class LoopEngine:
    """The daemon's loop itself, a cycle at a time: the reference the fast engine is held to."""

    def __init__(self, loop: ControlLoop):
        self.loop, self.cause = loop, ""

    def set_trajectory(self, path: trajectory.Trajectory, key=None) -> None:
        """The loop's own (``key``: the fast engine's sample sharing, none here)."""
        self.loop.set_trajectory(path, "path")

    @property
    def u(self) -> list[float]:
        return list(self.loop.u)

    def run(self, cycles: int, log: np.ndarray | None = None) -> bool:
        loop, n = self.loop, self.loop.n
        for i in range(cycles):
            loop.run(1)
            if loop.state.value != "enabled":
                self.cause = loop.supervisor.cause
                return False
            if log is not None:
                log[i, :n], log[i, n:2 * n], log[i, 2 * n:] = loop.reference[0], loop.angles, loop.u
        return True


def engine_for(loop: ControlLoop, cycles: int, engine: str, key=None):
    """``fast`` (refused where it does not apply: ValueError), ``loop``, or ``auto`` (fast where
    it applies); ``key`` names the reference in force (the fast engine's sample sharing)."""
    if engine == "loop" or (engine == "auto" and fast.refusal(loop)):
        return LoopEngine(loop)
    return fast.FastLoop(loop, cycles, key)


def run_case(rig: config.RigConfig, controller: str, plant: cases.Plant, name: str, path: trajectory.Trajectory,
             params: dict | None = None, options: dict | None = None, plugins: dict[str, str] | None = None,
             engine: str = "auto", trace: bool = False, log_out: list | None = None) -> Case:
    """One case (module docstring); ``trace`` keeps every TRACE_EVERY-th cycle for figures;
    ``log_out`` (a list) receives the whole per-cycle log (reference, angles, output)."""
    try:
        loop = make_loop(evaluation_rig(rig, plant, engine != "loop"), controller, params, options, plugins)
    except ConfigError:  # no compiled plant for this rig or these options: the Python one
        if engine == "fast":
            raise
        loop = make_loop(evaluation_rig(rig, plant, False), controller, params, options, plugins)
    case = Case(controller, plant.name, name, path.duration)
    start = path.sample(0.0)[0]
    move = trajectory.JointMove(list(loop.reference[0]), start, approach_duration(loop, start))
    loop.set_trajectory(move, "approach")
    before = round((move.duration + SETTLE_S) / loop.period)
    moving, after = round(path.duration / loop.period), round(HOLD_S / loop.period)
    runs = engine_for(loop, before + moving + after, engine, ("approach", tuple(move.q0), tuple(start), move.duration))
    if not runs.run(before):
        case.tripped = f"before the reference: {runs.cause}"
        return case
    u_before = runs.u
    runs.set_trajectory(path, (rig.hash, name, path.duration))
    log = np.full((moving + after, 2 * loop.n + loop.actuation.width), np.nan)
    if not runs.run(moving + after, log):
        case.tripped = runs.cause
    if log_out is not None:
        log_out.append(log)
    if trace:
        kept = log[::TRACE_EVERY]
        kept = kept[~np.isnan(kept[:, 0])]
        case.trace = {"t": (np.arange(len(kept)) * TRACE_EVERY * loop.period).tolist(),
                      "error_deg": np.degrees(kept[:, :loop.n] - kept[:, loop.n:2 * loop.n]).tolist()}
    if not case.tripped:
        figures(loop, path, log, u_before, case)
    return case


def figures(loop: ControlLoop, path: trajectory.Trajectory, log: np.ndarray, u_before: list[float], case: Case) -> None:
    """The case's figures (module docstring) from its log: a row per cycle from the reference's
    start, (reference [rad], angles [rad], output) each."""
    n, dt = loop.n, loop.period
    lengths = loop.rig.arm.link_lengths_m
    lo, hi = np.array(loop.context.u_min), np.array(loop.context.u_max)
    moving, tracked, after = round(path.duration / dt), round((path.duration + TAIL_S) / dt), round(HOLD_S / dt)
    ref, q, u = log[:, :n], log[:, n:2 * n], log[:, 2 * n:]
    errors = np.degrees(ref - q)
    worst = np.abs(errors).max(axis=1)
    tips = [_tip(x[:tracked], lengths) for x in (ref, q)]
    d = np.hypot(tips[0][0] - tips[1][0], tips[0][1] - tips[1][1]) * 1e3
    case.tip_max_mm, case.tip_rms_mm = float(d.max()), float(np.sqrt(np.sum(d * d) / tracked))
    e = errors[:tracked]
    case.joint_max_deg = float(np.abs(e).max())
    case.joint_rms_deg = float(np.sqrt((e * e).sum(axis=0) / tracked).max())
    if moving:
        run = u[:moving]
        case.at_limit_pct = 100.0 * float(((run <= lo) | (run >= hi)).sum(axis=0).max()) / moving
        steps = np.abs(np.diff(np.vstack([np.array(u_before)[None, :], run]), axis=0))
        case.motion_v_s = float(steps.sum(axis=0).max()) / path.duration
    outside = np.nonzero(worst[moving:] >= BAND_DEG)[0]
    last_out = int(outside[-1]) + 1 if len(outside) else 0  # cycles after the end until it stays inside
    flips, side = 0, [0] * n
    for row in u[moving + after - round(3.0 / dt):].tolist():
        for j in range(n):
            s = 1 if row[j] > HYSTERESIS_V else -1 if row[j] < -HYSTERESIS_V else side[j]
            flips += s != side[j] and side[j] != 0
            side[j] = s
    case.sign_changes_per_s = flips / 3.0
    case.final_deg = float(worst[-1])
    settled = case.final_deg < BAND_DEG
    case.settle_s = last_out * dt if settled else math.nan
    case.recovered = settled and last_out * dt <= RECOVER_S


def _tip(angles: np.ndarray, lengths) -> tuple[np.ndarray, np.ndarray]:
    """Tip (x, y) [m] per row of joint angles [rad], [2-7] (:func:`hal.kinematics.forward`)."""
    x = y = phi = 0.0
    for j, length in enumerate(lengths[:angles.shape[1]]):
        phi = phi + angles[:, j]
        x, y = x + length * np.cos(phi), y + length * np.sin(phi)
    return x, y
