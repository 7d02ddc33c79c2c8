"""``pneumactl replay RUN.mcap``: what the rig's model would have done in a recorded run
(docs/model.md). The recording's provenance gives the rig file, the controller in force when
the arm was enabled and its parameters (its start's, then its ``controller`` and ``params``
events), and its state samples the reference (each cycle's set-points); the daemon's own loop
(:func:`daemon.assembly.build_loop`, the supervisor, clamps and the simulated rig's sensors)
then runs that controller on the rig's model on a virtual clock, from the angles the arm was at,
following the recorded set-points (:class:`controllers.trajectory.Recorded`), a cycle for each
recorded one. ``--config`` replays on another rig file's model (a model to judge against the
arm).

The simulated rig is the rig file's with the simulator as its transport and the joints'
identified models as the plant (the recorded rig's own drifts and plant overrides, if it was a
simulator, left out: the model is what is asked about); its noise and seed are the file's.

What it says per joint: Fit [2-49] of the simulated against the measured position over the
replayed span, ``Fit = (1 - ||y - y_hat|| / ||y - mean(y)||) * 100 %``, the RMS and largest
difference [deg or mm], and where the two part: the first time the difference stays beyond
``part`` (default 1 deg, 1 mm) for ``PART_HOLD_S``. A recording without what a replay needs
is refused with what is missing (:class:`Refused`), as is an open-loop input experiment (its
joint's output was the signal, not the controller's).

Each recorded cycle runs at its recorded time: a loop that fell behind its period (a loaded
PC: cycles skipped, the output held meanwhile) is replayed so, the model's plant advancing over
the same time; cycles the recording left out (telemetry it lost) run in between at the period.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from controllers import registry
from controllers.trajectory import Recorded
from daemon import assembly
from daemon.loop.clock import VirtualClock
from daemon.recordings.reading import Run
from hal import config
from hal.errors import ConfigError

PART_HOLD_S = 0.2  # the difference beyond the limit this long: the two have parted [s]


class Refused(ValueError):
    """A recording a replay cannot use: what is missing, in words."""


def missing(run: Run) -> list[str]:
    """What ``run`` lacks for a replay (none: it can be replayed)."""
    out = []
    if not (run.describe.get("rig") or {}).get("source"):
        out.append("the rig file (describe.rig.source): a recording made before rig files were kept")
    if not (run.controller or {}).get("name"):
        out.append("the controller (the recording's controller metadata)")
    elif not isinstance(run.controller.get("params"), dict):
        out.append("the controller's parameters (the recording's controller metadata)")
    joints = run.layout.owners() if run.layout is not None else []
    names = set(run.layout.names) if run.layout is not None else set()
    for j in joints:
        for q in ("position", "setpoint"):
            if f"{j}.{q}" not in names:
                out.append(f"{j}.{q} in the state samples")
    if not run.samples:
        out.append("state samples (the recording holds none)")
    elif not any(s.get("mode") == "enabled" for s in run.samples):
        out.append("a span with the arm enabled (the recording never has it: nothing was controlled)")
    return out


def open_loop_in(run: Run, t0: float, t1: float) -> dict | None:
    """The open-loop input experiment run between ``t0`` and ``t1`` [s], if any (its
    ``experiment`` event: a joint's output was the signal, not the controller's)."""
    return next((e for e in run.messages.get("event", []) if e.get("kind") == "experiment"
                 and e.get("action") == "open_loop" and t0 <= e.get("t", -math.inf) <= t1), None)


def controller_at(run: Run, t: float) -> tuple[str, dict]:
    """The controller in force at ``t`` [s] and its parameters: the recording's start's, then its
    ``controller`` and ``params`` events up to ``t``."""
    name, params = run.controller["name"], dict(run.controller.get("params") or {})
    for e in run.messages.get("event", []):
        if e.get("t", math.inf) > t:
            break
        if e.get("kind") == "controller":
            name, params = e["to"], dict(e.get("params") or {})
        elif e.get("kind") == "params" and e.get("controller") == name:
            params = dict(e.get("params") or {})
    return name, params


def enabled_span(run: Run) -> tuple[int, int]:
    """(first, stop) sample indices of the first span with the arm enabled."""
    modes = [s.get("mode") for s in run.samples]
    first = modes.index("enabled")
    stop = first
    while stop < len(modes) and modes[stop] == "enabled":
        stop += 1
    return first, stop


def model_rig(rig: config.RigConfig, start_deg: dict[str, float]) -> config.RigConfig:
    """``rig`` with the simulator as its transport, the joints' own models as the plant, and each
    joint starting at ``start_deg`` (its noise and seed kept where it was a simulator); the
    tracking rule off (the replay shows where the model leaves the arm: it does not stop there)."""
    options = dict(rig.transport.options) if rig.transport.backend == "sim" else {}
    options["joints"] = {name: {"initial_angle_deg": a} for name, a in start_deg.items()}
    rig = config.with_transport(rig, "sim", options)
    return replace(rig, safety=replace(rig.safety, tracking_error_deg=0.0))


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> float:
    """[2-49]: (1 - ||y - y_hat|| / ||y - mean(y)||) * 100 %."""
    spread = float(np.linalg.norm(y - y.mean()))
    return (1.0 - float(np.linalg.norm(y - y_hat)) / spread) * 100.0 if spread > 0 else math.nan


def parted(t: np.ndarray, difference: np.ndarray, limit: float, hold_s: float = PART_HOLD_S) -> float | None:
    """The first time [s] ``|difference|`` stays beyond ``limit`` for ``hold_s``; None if never."""
    beyond = np.abs(difference) > limit
    since = None
    for k in range(len(t)):
        if not beyond[k]:
            since = None
        elif since is None:
            since = t[k]
        if since is not None and t[k] - since >= hold_s:
            return float(since)
    return None


def replay(run: Run, rig_text: str | None = None, part: float | None = None) -> dict:
    """The recorded run's first enabled span again on the rig's model (module docstring): per
    joint the measured and simulated positions and commands, the Fit, the RMS and largest
    difference, where they part. Refused (what is missing) if it cannot be."""
    lacking = missing(run)
    if lacking:
        raise Refused("cannot replay this recording: it has no " + "; no ".join(lacking))
    first, stop = enabled_span(run)
    samples = run.samples[first:stop]
    if len(samples) < 2:
        raise Refused("cannot replay this recording: its enabled span has fewer than two samples")
    experiment = open_loop_in(run, samples[0]["t"], samples[-1]["t"])
    if experiment is not None:
        raise Refused(f"cannot replay this recording: joint {experiment.get('joint')}'s output was an open-loop "
                      f"input experiment's signal from {experiment['t'] - samples[0]['t']:.1f} s, not its "
                      f"controller's; replay runs the recorded controller (`pneumactl identify --from` fits a model "
                      f"to it)")
    try:
        rig = config.parse(rig_text if rig_text is not None else run.describe["rig"]["source"], "<replayed rig>")
    except ConfigError as exc:
        raise Refused(f"cannot replay this recording: its rig file does not parse here: {exc}") from None
    layout = run.layout
    joints = layout.owners()
    if [j.name for j in rig.joints] != joints:
        raise Refused(f"cannot replay this recording on this rig: its joints are {joints}, the rig's "
                      f"{[j.name for j in rig.joints]}")
    units = {j: layout[f"{j}.position"].display for j in joints}
    t = np.array([s["t"] for s in samples]) - samples[0]["t"]
    cycles = np.array([s["cycle"] for s in samples], dtype=np.int64)
    measured = np.array([[s[f"{j}.position"] for j in joints] for s in samples], dtype=float)
    setpoints = np.array([[s[f"{j}.setpoint"] for j in joints] for s in samples], dtype=float)
    commands = [f.name for f in layout.of_group("command")]
    recorded_u = np.array([[s.get(c, math.nan) for c in commands] for s in samples], dtype=float)
    start = {j: float(np.degrees(measured[0, k])) if units[j][0] == "deg" else float(measured[0, k])
             for k, j in enumerate(joints)}
    name, params = controller_at(run, samples[0]["t"])
    sim = model_rig(rig, {j: a for j, a in start.items() if units[j][0] == "deg"})
    loop = assembly.build_loop(sim, VirtualClock(), 0.001, "hold", contact=False)
    try:
        loop.start()
        try:
            loop.switch(registry.build(name, loop.context, params))
        except (LookupError, ValueError) as exc:
            raise Refused(f"cannot replay this recording: its controller {name!r} with its recorded parameters "
                          f"cannot be built here: {exc}") from None
        loop.enable()
        loop.set_trajectory(Recorded(t, setpoints), "replay")
        t0 = loop.trajectory_t0  # the recorded span's start on the model's clock
        simulated, sim_u, tripped = np.full_like(measured, np.nan), np.full_like(recorded_u, np.nan), ""
        for k in range(len(t)):
            for _ in range(int(cycles[k] - cycles[k - 1]) - 1 if k else 0):
                loop.run(1)  # cycles the recording left out (telemetry it lost): run, at the period
            loop.run_at(t0 + t[k])  # this one at its recorded time: a loop that fell behind its period did so here
            if loop.state.value != "enabled":
                tripped = f"the replay left enabled at {t[k]:.3f} s: {loop.supervisor.cause}"
                break
            simulated[k] = loop.angles
            sim_u[k] = loop.u
    finally:
        loop.stop()
        loop.io.transport.close()
    out = {"controller": name, "params": params, "duration_s": float(t[-1]), "tripped": tripped, "joints": {},
           "t": t, "measured": measured, "simulated": simulated, "setpoints": setpoints,
           "commands": commands, "command_units": [layout[c].unit for c in commands], "recorded_u": recorded_u,
           "simulated_u": sim_u, "units": units}
    for k, j in enumerate(joints):
        unit, scale = units[j]
        y, y_hat = measured[:, k] * scale, simulated[:, k] * scale
        ok = np.isfinite(y) & np.isfinite(y_hat)
        d = y[ok] - y_hat[ok]
        limit = part if part is not None else 1.0
        out["joints"][j] = {"fit_percent": fit_percent(y[ok], y_hat[ok]) if ok.sum() > 1 else math.nan,
                            f"rms_{unit}": float(np.sqrt(np.mean(d * d))) if len(d) else math.nan,
                            f"max_{unit}": float(np.abs(d).max()) if len(d) else math.nan,
                            "part_limit": limit, "unit": unit, "parted_s": parted(t[ok], d, limit)}
    return out
