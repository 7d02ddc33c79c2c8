"""One joint's experiments, from a recording the caller has read (MCAP or .pnrec: the daemon's
``daemon.recordings.reading.Run``, or anything with its ``describe``, ``messages`` and
``column(name)``: a field of the cycle record as an array, SI, by the record's names:
``<joint>.position``, ``<joint>.setpoint``, ``<joint>.u.v_mv``, the commanded chamber pressures
``<joint>.p_head_cmd`` and ``<joint>.p_rod_cmd``), with the signals rebuilt by the caller's ``rebuild`` (the daemon's is
``daemon.wire.signals.recorded``): controllers never import the daemon.

An experiment is found by its ``reference`` start event, which carries the signal's settings
(``excite``'s ``signal``: side, joint, amplitude, operating point). An input-side one starts
at its ``experiment`` ``open_loop`` event (the operating point's V_MV, ``u_op_v``) and ends at
its reference's end or its ``abort``; a reference-side one spans its reference. The rig's
source text and hash come from the recording's ``describe``, so the prior model the fit
starts from is the one the daemon ran with.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from controllers.identification.fit import Experiment
from controllers.signals import Excitation
from hal import config
from hal.identified import JointParams
from hal.regulator import ITV0051


Rebuild = Callable[[dict], Excitation]  # a recorded signal definition -> the signal that ran


def rig_of(run) -> config.RigConfig:
    """The rig configuration the recording was made with (its source text)."""
    rig = run.describe["rig"]
    return config.parse(rig["source"], rig.get("origin") or "<recording>")


def prior_of(rig: config.RigConfig, joint: str) -> JointParams:
    """The model the rig gave the joint: where the fit starts, and its geometry."""
    for j in rig.joints:
        if j.name == joint:
            params = rig.joint_params(j)
            if params is None:
                raise ValueError(f"joint {joint} has no model in the rig file: give it [[joints]] model")
            return params
    raise ValueError(f"no joint {joint!r} in the rig (joints: {', '.join(j.name for j in rig.joints)})")


def experiments(run, source: str, rebuild: Rebuild, joint: str | None = None) -> list[Experiment]:
    """Every experiment in a recording ``run`` read from ``source`` (on ``joint``, if given), in order."""
    rig = rig_of(run)
    events = run.messages.get("event", [])
    found = []
    for i, ev in enumerate(events):
        signal = ev.get("signal") if ev.get("kind") == "reference" and ev.get("action") == "start" else None
        if not signal or (joint is not None and signal["joint"] != joint):
            continue
        generation = ev["generation"]
        later = events[i + 1:]
        end = next((e for e in later if e.get("kind") == "reference" and e.get("action") == "end"
                    and e.get("generation") == generation), None)
        abort = next((e for e in later if e.get("kind") == "experiment" and e.get("action") == "abort"
                      and (end is None or e["cycle"] <= end["cycle"])), None)
        if signal["side"] == "input":
            opened = next((e for e in later if e.get("kind") == "experiment" and e.get("action") == "open_loop"), None)
            if opened is None:
                continue
            first, u_op = opened["cycle"], opened["u_op_v"]
        else:
            first, u_op = ev["cycle"], None
        last = min(c["cycle"] for c in (end, abort, {"cycle": math.inf}) if c is not None)
        info = {"source": source, "rig_hash": run.describe["rig"]["hash"], "signal": signal, "u_op_v": u_op,
                "start_cycle": first, "aborted": abort["cause"] if abort else "", "cut": (end or {}).get("cut", "")}
        found.append(_experiment(run, rig, signal["joint"], first, last, info, rebuild))
    return found


def _experiment(run, rig: config.RigConfig, joint: str, first: int, last: float, info: dict,
                rebuild: Rebuild) -> Experiment:
    cycles = np.asarray(run.column("cycle"))
    rows = (cycles >= first) & (cycles < last)
    if rows.sum() < 100:
        raise ValueError(f"{info['source']}: the {info['signal']['signal']} on {joint} has {rows.sum()} samples "
                         f"recorded: too few to analyse (was the recording started before it?)")
    cycles = cycles[rows]
    if np.any(np.diff(cycles) != 1):
        missing = int(np.sum(np.diff(cycles) - 1))
        raise ValueError(f"{info['source']}: {missing} cycles of the experiment are missing from the recording "
                         f"(a subscriber too slow?): record it with the daemon's recorder (record: true)")
    prior = prior_of(rig, joint)
    t = np.asarray(run.column("t"), dtype=float)[rows]
    # the angle [rad], V_MV [V], the commanded chamber pressures [Pa] and the set-point [rad]
    data = {k: np.asarray(run.column(f"{joint}.{k}"), dtype=float)[rows]
            for k in ("position", "u.v_mv", "p_head_cmd", "p_rod_cmd", "setpoint")}
    # the pressures are changes from those that held the joint at rest before: for an input-side
    # experiment the operating point's V_MV through the head regulator (its first command
    # already carries the signal, and may be slew-limited)
    head_ref = data["p_head_cmd"][0]
    if info["u_op_v"] is not None:
        jc = next(j for j in rig.joints if j.name == joint)
        head_ref = ITV0051(jc.head).pressure(jc.head.bias_volts + info["u_op_v"])
    lever = prior.L * (prior.area_head * (data["p_head_cmd"] - head_ref)
                       - prior.area_rod * (data["p_rod_cmd"] - data["p_rod_cmd"][0]))
    period = float(run.describe.get("period_s") or np.median(np.diff(t)))
    grid, held, angle, time_base = on_the_period(t, period, data["position"])
    if info["signal"]["side"] == "input":
        # the instrument of the joint input-output method [V]: the input-side signal as the
        # planner built it, on the loop's clock from the open-loop phase's first cycle
        r = rebuild(info["signal"]).series(grid - grid[0])
    else:
        r = np.degrees(data["setpoint"] - data["setpoint"][0])[held]  # [deg]
    y = np.degrees(angle - angle[0])
    return Experiment(period, lever[held], y, grid - grid[0], data["u.v_mv"][held], float(np.degrees(angle[0])),
                      {**info, "joint": joint, "time_base": time_base}, r)


def on_the_period(t: np.ndarray, period: float, angle: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The experiment on a uniform grid at the loop's ``period`` [s], by the samples' own times
    ``t`` [s] (each row's input sweep): the fit's model steps at a fixed period, and a loop
    that ran late (behind a slow wire, without real-time priority) stretches wall time under
    its cycles, so rows read as one period apart would make the plant look faster than it is.
    Rows whose sample repeats the one before (a stale sample, reused) are placed evenly between
    the fresh ones. Returns the grid [s], each grid time's row (the commands in force then:
    zero-order hold), the angle [rad] interpolated between fresh samples, and what was done."""
    n = len(t)
    fresh = np.flatnonzero(np.diff(t, prepend=-np.inf) > 0.0)
    times = np.interp(np.arange(n), fresh, t[fresh])  # monotone: a stale row between its neighbours
    grid = times[0] + period * np.arange(int((times[-1] - times[0]) / period + 1e-6) + 1)
    held = np.clip(np.searchsorted(times, grid + 1e-6 * period, side="right") - 1, 0, n - 1)
    span = float(times[-1] - times[0])
    return grid, held, np.interp(grid, t[fresh], angle[fresh]), {
        "period_s": period, "mean_period_s": span / max(n - 1, 1), "stale_fraction": 1.0 - len(fresh) / n,
        "lost_s": span - period * (n - 1)}
