"""Identification data from any closed-loop recording (paths, steps, waypoints, under any
controller): the joint model [2-36..2-45] is an output-error model from the commanded chamber
pressures to the angle, so the loop that chose the commands does not enter it; what matters is
whether the commands moved the joint enough, and in enough ways, to tell the parameters apart.

The run is the recording's longest span with the arm enabled, from the joint's first rest in it
(the fit's model starts at rest: :mod:`.simulate`). The first ``ESTIMATION_FRACTION`` of it is
fitted; the model then runs on from the start through the rest of the run with the fitted
parameters and the start's friction torque the fit chose, and the [2-49] Fit over that tail
is the held-out Fit: data the fit did not see.

Before a fit, :func:`excitation` says what the run lacks (rig-facts §1 "Identified joint model";
docs/identification.md "From any recording"):

- **motion**: the angle's spread (1st to 99th percentile) under ``MIN_MOTION_DEG``;
- **saturation**: a chamber's command at a regulator's end (0.001 or 0.9 MPa, [2-29]) more than
  ``MAX_SATURATED`` of the time (the plant then sees a constant);
- **spectral lines**: the pressure lever's spectrum has fewer than ``MIN_LINES`` frequencies
  above ``LINE_FLOOR`` of its peak between the run's lowest frequency and the regulator's corner
  1/(2 pi T_ep): each line gives a gain and a phase, so the six fitted parameters need three;
- **information**: the smallest eigenvalue of the information matrix J^T J (J: the output
  error's sensitivity to the fitted parameters at the prior, each column in relative terms)
  below ``MIN_INFORMATION`` of the largest: some combination of parameters (named by the
  weakest eigenvector) leaves the output unchanged. Above it the fit is made; the weakest
  direction is named, and the parameters that weigh in directions under ``UNSETTLED`` are
  said to be unsettled: the run trades them against each other (a slow path pins the sum of
  the regulator's lag and the dead time, not each), and the fit's stated uncertainty, made at
  its optimum, does not cover that trade.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from controllers.identification import data as experiments_of
from controllers.identification.fit import SEARCH, Experiment, _Problem, fit_percent, predict
from controllers.identification.simulate import samples_per_step
from hal.identified import JointParams, P_SET_MAX, P_SET_MIN

ESTIMATION_FRACTION = 0.7  # the run's first part, fitted; the rest held out
MIN_SPAN_S = 10.0  # a run shorter than this is not fitted [s]
MIN_MOTION_DEG = 1.0  # the angle's 1-99 % spread below this is too little motion [deg]
MAX_SATURATED = 0.5  # a chamber's command at a regulator's end more of the time than this [-]
SATURATION_PA = 1e3  # within this of a regulator's end is at it [Pa]
MIN_LINES, LINE_FLOOR = 3, 0.01  # spectral lines needed, and a line's power against the peak [-]
# the information matrix's smallest eigenvalue against its largest [-]: identify's own experiments
# on the simulated joints reach 4e-7 (a chirp: T_ep against T_dly) to 2e-6, waypoints 2 s apart
# 6e-9 (the middle joint: T_ep against T_dly, their sum pinned) to 2e-6; an arm held still, 0
MIN_INFORMATION = 1e-10
# a fitted parameter weighing 0.4 or more in an eigen-direction under this of the largest is
# unsettled: on waypoints 2 s apart (docs/identification.md) the converged fit missed those
# (T_ep, T_dly, Fs, Fc) by up to 60 % while stating 5 %, and met the others (D, K) within 2 sigma
UNSETTLED = 1e-4
REST_S, REST_SPREAD_DEG = 0.5, 0.2  # at rest: the angle's 20 ms means within this spread over this long [s, deg]
REST_SPREAD_PA = 10e3  # ... and the commanded pressures' within this [Pa] (a PI holding the arm moves them slowly)
SMOOTH_S = 0.02  # the angle is judged at rest on means over this [s] (the potentiometer's noise averaged)
NOT_RECORDED = "closed loop"  # the experiment's signal name for a closed-loop run


def enabled_span(run) -> tuple[int, int]:
    """(first, stop) sample indices of the recording's longest span with the arm enabled
    ((0, 0): none)."""
    best, first = (0, 0), None
    modes = [s.get("mode") for s in run.samples] + [None]
    for i, mode in enumerate(modes):
        if mode == "enabled" and first is None:
            first = i
        elif mode != "enabled" and first is not None:
            best, first = max(best, (first, i), key=lambda s: s[1] - s[0]), None
    return best


def start_of(angle_deg: np.ndarray, head_pa: np.ndarray, rod_pa: np.ndarray, dt: float) -> tuple[int, bool]:
    """Where the fit starts (its model starts at rest, its chambers settled on the commands in
    force): the end of the first REST_S over which the means over SMOOTH_S of the angle stay
    within REST_SPREAD_DEG and of both commanded pressures within REST_SPREAD_PA, and True;
    without such a rest in the run's first third, the slowest moment there (the least change
    of the angle between two means), and False."""
    m = max(int(SMOOTH_S / dt), 1)
    usable = len(angle_deg) // m * m

    def means(x):
        return np.asarray(x[:usable], dtype=float).reshape(-1, m).mean(axis=1)
    angle, head, rod = means(angle_deg), means(head_pa), means(rod_pa)
    n = max(int(REST_S / (m * dt)), 2)
    third = max(len(angle) // 3, n + 1)
    for k in range(0, min(third, len(angle) - n)):
        window = slice(k, k + n)
        if (np.ptp(angle[window]) < REST_SPREAD_DEG and np.ptp(head[window]) < REST_SPREAD_PA
                and np.ptp(rod[window]) < REST_SPREAD_PA):
            return (k + n) * m, True
    speed = np.abs(np.diff(angle[:third]))
    return (int(np.argmin(speed)) * m if len(speed) else 0), False


def run_experiment(run, source: str, joint: str) -> Experiment:
    """The joint's closed-loop run in recording ``run`` (read from ``source``) as an
    experiment: the commanded pressures' lever and the angle, from its first rest.
    ValueError when the recording holds no enabled span long enough, or not the joint's
    commanded chamber pressures (only a cylinder joint on regulators is fitted)."""
    if f"{joint}.p_head_cmd" not in run.layout:
        raise ValueError(f"{source}: no commanded chamber pressures of joint {joint!r} in the recording "
                         f"(joints: {', '.join(run.layout.owners())}): the model fitted is a cylinder joint's "
                         f"on its regulators")
    first, stop = enabled_span(run)
    cycles = np.asarray(run.column("cycle")) if run.samples else np.zeros(0)
    dt = float(run.describe.get("period_s") or 0.001)
    if stop - first < MIN_SPAN_S / dt:
        held = (stop - first) * dt
        raise ValueError(f"{source}: the arm is enabled for {held:.1f} s at most: a run of {MIN_SPAN_S:g} s "
                         f"at least is needed to fit (record a path with the arm enabled)")
    head, rod = (run.column(f"{joint}.{k}")[first:stop] for k in ("p_head_cmd", "p_rod_cmd"))
    offset, rest = start_of(np.degrees(run.column(f"{joint}.position")[first:stop]), head, rod, dt)
    start = first + offset
    info = {"source": source, "rig_hash": run.describe["rig"]["hash"], "u_op_v": None, "aborted": "", "cut": "",
            "signal": {"signal": NOT_RECORDED, "side": "reference", "joint": joint},
            "start_cycle": int(cycles[start]), "from_rest": rest,
            "saturated_fraction": saturated_fraction(head[offset:], rod[offset:])}
    return experiments_of._experiment(run, experiments_of.rig_of(run), joint, int(cycles[start]),
                                      int(cycles[stop - 1]) + 1, info, None)


def split(e: Experiment, fraction: float = ESTIMATION_FRACTION) -> Experiment:
    """The run's first ``fraction``: what is fitted."""
    n = int(len(e.y) * fraction)
    r = e.r[:n] if e.r is not None else None
    return dataclasses.replace(e, lever=e.lever[:n], y=e.y[:n], t=e.t[:n], u=e.u[:n], r=r,
                               info={**e.info, "part": f"first {fraction:.0%}"})


def tail_fit(params: JointParams, whole: Experiment, fitted: Experiment, step: float,
             c: float) -> tuple[float, float, np.ndarray]:
    """[2-49] over the part of ``whole`` after ``fitted``: the model run from the start on the
    whole run's commands with the fit's own start ``c`` [N m] (nothing chosen on the tail); the
    Fit [%], the residual's RMS there [deg], and the model's angle on the step grid [deg]."""
    m = samples_per_step(step, whole.dt)
    target = whole.y[m::m]
    y_hat = predict(params, whole, step, c)[:len(target)]
    tail = slice(len(fitted.y[m::m]), len(y_hat))
    return (fit_percent(target[tail], y_hat[tail]), float(np.sqrt(np.mean((target[tail] - y_hat[tail]) ** 2))),
            y_hat)


def excitation(e: Experiment, prior: JointParams, step: float = 0.005) -> list[str]:
    """What the run ``e`` lacks for a fit of its joint (none: it supports one), in words."""
    joint, out = e.info["joint"], []
    spread = float(np.percentile(e.y, 99) - np.percentile(e.y, 1))
    if spread < MIN_MOTION_DEG:
        out.append(f"it moved {spread:.2f} deg over the run (1-99 % of its samples): too little to fit, "
                   f"{MIN_MOTION_DEG:g} deg at least")
    saturated = e.info.get("saturated_fraction", 0.0)
    if saturated > MAX_SATURATED:
        out.append(f"a chamber's command is at a regulator's end {saturated:.0%} of the time: the plant saw a "
                   f"constant there")
    lines, band = spectral_lines(e.lever, e.dt, e.t[-1] - e.t[0], prior.T_ep)
    if lines < MIN_LINES:
        out.append(f"its commands hold {lines} frequency line(s) between {band[0]:.2g} and {band[1]:.2g} Hz "
                   f"above {LINE_FLOOR:.0%} of the strongest: {MIN_LINES} at least are needed for the model's "
                   f"order (a gain and a phase each, six parameters)")
    if not out:
        ratio, weakest, _ = information(e, prior, step)
        if not ratio >= MIN_INFORMATION:
            out.append(f"the information matrix's smallest eigenvalue is {ratio:.1e} of its largest (at least "
                       f"{MIN_INFORMATION:.0e}): the run does not tell {weakest} from the rest")
    return [f"joint {joint}: {what}" for what in out]


def spectral_lines(lever: np.ndarray, dt: float, span_s: float, t_ep: float) -> tuple[int, tuple[float, float]]:
    """How many frequency bins of the lever's spectrum (Hann window) between 1/span and the
    regulator's corner 1/(2 pi T_ep) hold at least LINE_FLOOR of the strongest one's power, and
    that band [Hz]."""
    x = np.asarray(lever, dtype=float)
    x = x - np.mean(x)
    power = np.abs(np.fft.rfft(x * np.hanning(len(x)))) ** 2
    f = np.fft.rfftfreq(len(x), dt)
    band = (1.0 / max(span_s, dt), 1.0 / (2.0 * math.pi * t_ep))
    inside = power[(f >= band[0]) & (f <= band[1])]
    if not len(inside) or inside.max() <= 0.0:
        return 0, band
    return int(np.sum(inside >= LINE_FLOOR * inside.max())), band


def information(e: Experiment, prior: JointParams, step: float) -> tuple[float, str, list[str]]:
    """The information matrix J^T J of the output error at ``prior`` (J's columns in relative
    terms: log parameters as they are, the dead time per the prior's, the start's friction
    torque per the prior's Fs): its smallest eigenvalue against its largest, the parameters its
    eigenvector weighs most, and the fitted parameters the run leaves unsettled (weighing 0.4 or
    more in a direction whose eigenvalue is under UNSETTLED of the largest)."""
    problem = _Problem(prior, [e], step)
    names = [*SEARCH[:-1], "c"]
    x = np.zeros(len(names))
    x[names.index("T_dly")] = prior.T_dly
    x[names.index("Fc_ratio")] = prior.Fc / prior.Fs
    scale = np.ones(len(names))
    scale[names.index("T_dly")] = max(prior.T_dly, 0.01)
    scale[names.index("c")] = prior.Fs
    jac = problem.jacobian(x) * scale
    eigen, vectors = np.linalg.eigh(jac.T @ jac)
    if eigen[-1] <= 0.0:
        return 0.0, "any parameter", list(SEARCH[:-1])
    weights = np.abs(vectors[:, 0])
    named = [names[i] for i in np.argsort(weights)[::-1] if weights[i] >= 0.5 * weights.max()]
    weak = np.abs(vectors[:, eigen < UNSETTLED * eigen[-1]])
    unsettled = [n for i, n in enumerate(names[:-1]) if weak.size and weak[i].max() >= 0.4]
    return (float(max(eigen[0], 0.0) / eigen[-1]), " and ".join(n.replace("_ratio", "") for n in named),
            unsettled)


def saturated_fraction(head_pa: np.ndarray, rod_pa: np.ndarray) -> float:
    """The fraction of samples either chamber's command is within SATURATION_PA of a regulator's
    end (P_SET_MIN, P_SET_MAX [Pa], [2-29])."""
    def at_end(p):
        return (p <= P_SET_MIN + SATURATION_PA) | (p >= P_SET_MAX - SATURATION_PA)
    return float(np.mean(at_end(head_pa) | at_end(rod_pa))) if len(head_pa) else 0.0
