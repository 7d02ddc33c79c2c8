"""``pneumactl identify JOINT``: excite, record, fit, plot, write the rig file, in one command
(rig-facts §1 "Experiments"; the analysis is :mod:`controllers.identification`).

The experiments are open loop on the joint's V_MV about its present set-point (the other
joints held by feedback): an M-sequence (PRBS) and the thesis's 0.1-1 Hz log chirp, which the
fit uses, then a second M-sequence of other bits it does not see (held out: the Fit % that
judges the model). The
telemetry is recorded here, as MCAP (and by the daemon too, ``record: true``); the fit runs
here, in the client's process, never in the daemon's. ``--from FILE`` analyses a recording
made earlier instead.
"""
from __future__ import annotations

import json
import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from controllers.identification import data as experiments_of
from controllers.identification import frf, plots, rigfile
from controllers.identification.fit import C_SPAN, fit_joint, heldout_fit
from controllers.identification.simulate import FITTED
from controllers.nominal import NominalJoint
from daemon.recordings import mcap_log
from daemon.recordings import reading as recording
from daemon.wire import protocol as P
from daemon.wire.signals import recorded
from daemon.client.client import Client, Interrupted, RemoteError, abort_started
from daemon.client.fit_report import against_prior, print_table, ran_late, residual_rms
from daemon.client.routine_lease import routine_lease
from hal import config
from hal.identified import UNITS

THESIS_BAND_HZ = (0.1, 1.0)
REST_DEG, REST_SPREAD_DEG, REST_S = 0.5, 0.2, 0.5  # at rest: within [deg] of the set-point, spread [deg], over [s]
# the experiments' centring PI crossover [Hz] (controllers/experiment.py): at the planner's default
# 0.03 Hz the reconstructed rig's middle joint (fast, on a weak spring) drifted out of its band (issue 32)
CENTRE_HZ = 0.1


@dataclass(frozen=True)
class Plan:
    """The experiments, in order, as (signal, settings): the last is held out of the fit
    (``quick``: about half as long, for a first look)."""

    experiments: tuple[tuple[str, dict], ...]
    settle_s: float = 2.0

    @classmethod
    def of(cls, quick: bool) -> "Plan":
        if quick:
            return cls((("prbs", {"order": 7, "bit_s": 0.1}),
                        ("chirp", {"f0_hz": 0.1, "f1_hz": 1.0, "duration_s": 15.0}),
                        ("prbs", {"order": 6, "bit_s": 0.2})))
        return cls((("prbs", {"order": 8, "bit_s": 0.1}),
                    ("chirp", {"f0_hz": 0.1, "f1_hz": 1.0, "duration_s": 30.0}),
                    ("prbs", {"order": 7, "bit_s": 0.17})))


def default_amplitude(params, u_op: float, u_range: tuple[float, float]) -> float:
    """V_MV amplitude [V]: enough torque to break static friction twice over (2.5 Fs of
    torque), at least 1 V, within 90 % of the room the operating point leaves in V_MV."""
    room = 0.9 * min(u_op - u_range[0], u_range[1] - u_op)
    return max(min(max(1.0, 2.5 * params.Fs / params.torque_per_volt), room), 0.05)


def holding_volts(rig, joint: str, setpoint_deg: float) -> float:
    """V_MV the rig's model says holds the joint at ``setpoint_deg`` [V] (0 without a model)."""
    jc = next(j for j in rig.joints if j.name == joint)
    model = NominalJoint.from_rig(jc, rig.joint_params(jc))
    return model.static_volts(math.radians(setpoint_deg), 0.0, 0.0) if model is not None else 0.0


def run_experiments(client: Client, joint: str, path: Path, plan: Plan, amplitude: float | None,
                    at_deg: list[float] | None, band_deg: float) -> None:
    """Run the plan's experiments on ``joint`` while recording to ``path``."""
    describe = client.describe()
    rig = config.parse(describe["rig"]["source"], "<daemon>")
    names = client.layout().owners()
    if joint not in names:
        raise SystemExit(f"no joint {joint!r} (joints: {', '.join(names)})")
    if client.status()["state"] != "enabled":
        raise SystemExit("the arm is not enabled: `pneumactl enable` first (identification moves it)")
    j = names.index(joint)
    prior = experiments_of.prior_of(rig, joint)
    with routine_lease(client):  # handed back at the end, Ctrl-C included (a lapsed one trips the enabled arm)
        stop, heard = threading.Event(), threading.Event()
        recorder = threading.Thread(target=mcap_log.record, args=(client, str(path), math.inf, None, stop, heard),
                                    name="identify-record", daemon=True)
        recorder.start()
        try:
            heard.wait(mcap_log.HEARD_LIMIT_S + 5.0)  # the recording has the subscription
            here = setpoints_deg(client, names)
            target = operating_point(rig, j, at_deg or here, band_deg)
            if any(abs(a - b) > 0.01 for a, b in zip(target, here)):
                reply = _move(client, target, here)
                _wait(client, reply.get("duration_s", 0.0), "the move to the operating point")
                _wait_for_rest(client, joint)
            for signal, settings in plan.experiments:
                u_op = holding_volts(rig, joint, setpoints_deg(client, [joint])[0])
                reply = _excite(client, joint, j, describe, prior, signal, settings, plan.settle_s, amplitude, band_deg,
                                u_op)
                _wait(client, reply["duration_s"], f"{signal} on {joint}")
                _wait_for_rest(client, joint)  # each experiment starts at rest: the fit assumes it
        except (KeyboardInterrupt, Interrupted):  # it stops what it started: the experiment running
            stopped = abort_started(client, "the experiment running")
            raise Interrupted(f"interrupted: identification stopped; {stopped}; "
                              f"the experiments so far are in {path}; nothing was fitted") from None
        finally:
            stop.set()
            recorder.join(5.0)


def operating_point(rig, j: int, angles_deg: list[float], band_deg: float) -> list[float]:
    """``angles_deg`` with joint j brought inside its limits by the band and a degree to spare, and
    at least by the rig's set-point margin (``[safety] setpoint_margin_deg``: a set-point closer is refused)."""
    jc = rig.joints[j]
    inside = max(band_deg + 1.0, rig.safety.setpoint_margin_deg)
    lo, hi = jc.min_angle_deg + inside, jc.max_angle_deg - inside
    if lo > hi:
        raise SystemExit(f"joint {jc.name}'s range {jc.min_angle_deg:g}..{jc.max_angle_deg:g} deg is too narrow "
                         f"for a band of +- {band_deg:g} deg: choose a smaller --band")
    out = list(angles_deg)
    out[j] = min(max(out[j], lo), hi)
    return out


def move_duration(target: list[float], here: list[float]) -> float:
    """A first guess at an unhurried move [s]: 2 deg/s on the joint that moves most, 3 s at least."""
    return max(3.0, max(abs(a - b) for a, b in zip(target, here)) / 2.0)


def _move(client: Client, target: list[float], here: list[float]) -> dict:
    """Move to the operating point; slower, as the daemon says it must be, if refused."""
    try:
        return client.set(angles_deg=target, duration_s=move_duration(target, here))
    except RemoteError as exc:
        shortest = (exc.data or {}).get("shortest_s")
        if exc.code != P.REFUSED or not shortest:
            raise
        return client.set(angles_deg=target, duration_s=1.25 * shortest)


def _excite(client, joint, j, describe, prior, signal, settings, settle_s, amplitude, band_deg, u_op) -> dict:
    """Start one experiment (the daemon records it too)."""
    u_range = v_mv_range(describe, joint)
    args = {**settings, "settle_s": settle_s, "band_deg": band_deg, "centre_hz": CENTRE_HZ}
    return excite_fitting(lambda volts: client.excite_input(signal, joint, volts, record=True, **args), signal,
                          amplitude if amplitude is not None else default_amplitude(prior, u_op, u_range),
                          fixed=amplitude is not None)


def excite_fitting(send, signal: str, volts: float, fixed: bool) -> dict:
    """``send(volts)``'s reply; an amplitude the daemon finds too large (``input_range``,
    ``excursion``) is scaled to what its numbers say would fit and tried again, at most three
    times, unless the user ``fixed`` it."""
    for _ in range(4):
        try:
            return send(volts)
        except RemoteError as exc:
            data = exc.data or {}
            if exc.code != P.REFUSED or fixed or data.get("reason") not in ("input_range", "excursion"):
                raise
            if data["reason"] == "input_range":
                lo, hi = data["range_v"]
                volts *= 0.9 * min(data["u_op_v"] - lo, hi - data["u_op_v"]) / data["peak_v"]
            else:
                volts *= 0.8 * data["band_deg"] / data["predicted_deg"]
            print(f"{signal}: {exc.message}; trying {volts:.2f} V", file=sys.stderr)
    raise SystemExit(f"no amplitude for the {signal} fits the rig here: choose one with --amplitude")


def _wait(client: Client, seconds: float, what: str) -> None:
    from daemon.client.progress import follow  # rich: only for the progress display
    outcome = follow(client, seconds)
    if not outcome["ended"]:
        raise SystemExit(f"{what}: the arm left the enabled state ({outcome['state']}: {outcome['cause']})")


def setpoints_deg(client: Client, names: list[str]) -> list[float]:
    """The joints' set-points [deg], as the latest cycle record has them."""
    row = client.sample()
    return [math.degrees(row[f"{n}.setpoint"]) for n in names]


def v_mv_range(describe: dict, joint: str) -> tuple[float, float]:
    """The joint's V_MV range [V], as ``describe``'s command interfaces declare it."""
    c = next((c for c in describe["command_interfaces"] if c["joint"] == joint and c["name"] == "v_mv"), None)
    if c is None:
        raise SystemExit(f"joint {joint} takes no V_MV (its actuation is not a cylinder's regulator pair): "
                         f"identification excites V_MV")
    return c["low"], c["high"]


def _wait_for_rest(client: Client, joint: str, timeout_s: float = 30.0) -> None:
    """Until feedback has brought the joint back to its set-point and it has stopped: over
    REST_S, every angle within REST_DEG of the set-point and their spread under REST_SPREAD_DEG
    (the telemetry's velocity is too noisy to judge rest by). On after ``timeout_s``, saying so."""
    start = time.monotonic()
    window: list[tuple[float, float, float]] = []
    with client.latest() as feed:
        while time.monotonic() - start < timeout_s:
            row = feed.row()
            now = time.monotonic()
            window = [w for w in window if now - w[0] <= REST_S] + [
                (now, math.degrees(row[f"{joint}.position"]), math.degrees(row[f"{joint}.setpoint"]))]
            angles = [a for _, a, _ in window]
            if (now - window[0][0] >= 0.9 * REST_S and max(angles) - min(angles) < REST_SPREAD_DEG
                    and all(abs(a - r) < REST_DEG for _, a, r in window)):
                return
            time.sleep(0.05)
    print(f"note: joint {joint} not at rest after {timeout_s:g} s; the next experiment starts anyway", file=sys.stderr)


def analyse(path: Path, joint: str, out: Path, population: int, generations: int, seed: int = 0) -> dict:
    """Fit the recording's experiments on ``joint`` (all but the last; the last is held out),
    or, a recording without any (a path, steps, waypoints, under any controller), its closed-loop
    run (:mod:`daemon.client.refit`); write the figures, the rig file and a report into ``out``;
    the report. A cut recording is refused: what is missing would be taken for the run's end."""
    try:
        run = recording.open_run(path)
        if run.truncated:
            raise SystemExit(f"{run.cut_notice(str(path))}: identification fits a whole recording "
                             f"(record the run again)")
        found = experiments_of.experiments(run, str(path), recorded, joint)
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted: reading {path} stopped; nothing was fitted or written") from None
    if not found:
        from daemon.client.refit import refit
        return refit(run, Path(path), joint, out, population, generations, seed)
    aborted = [e.info["aborted"] for e in found if e.info["aborted"]]
    if aborted:
        raise SystemExit(f"{path}: an experiment was stopped: {aborted[0]}: lower the amplitude or widen the band")
    if len(found) < 2:
        raise SystemExit(f"{path}: {len(found)} experiment(s) on {joint}: two at least are needed (one held out)")
    for e in found:
        base = e.info["time_base"]
        if ran_late(base):
            print(f"note: the loop ran late during the {e.info['signal']['signal']} (a cycle every "
                  f"{base['mean_period_s'] * 1e3:.3f} ms for {base['period_s'] * 1e3:g} ms, "
                  f"{base['stale_fraction']:.0%} of its samples stale): it is analysed on the samples' own times",
                  file=sys.stderr)
    estimation, held_out = found[:-1], found[-1:]
    rig = experiments_of.rig_of(run)
    prior = experiments_of.prior_of(rig, joint)
    try:
        result = fit_joint(estimation, prior, held_out, population=population, generations=generations, seed=seed,
                           progress=_fit_progress(generations))
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted: the fit of {joint} to {path} stopped; nothing was written "
                          f"(`pneumactl identify {joint} --from {path}` fits it again)") from None
    # the prior judged on the same held-out data, the same way (only its start's held friction chosen)
    prior_fit = heldout_fit(prior, held_out[0], result.settings["step_s"], C_SPAN * prior.Fs)
    judged = {"heldout_fit_percent": result.heldout_fit_percent[0],
              "heldout_rms_deg": residual_rms(result.heldout_fit_percent[0], held_out[0], result.settings["step_s"])}
    verdict = against_prior(result.heldout_fit_percent[0], prior_fit, [e.info["time_base"] for e in found])
    out.mkdir(parents=True, exist_ok=True)
    labels = [f"{e.info['signal']['signal']} ({'held out' if i == len(found) - 1 else 'fitted'})"
              for i, e in enumerate(found)]
    responses = [(label, frf.estimate(e, period_s=frf.period_of(recorded(e.info["signal"])))) for label, e in zip(labels, found)]
    bode = plots.bode(out / f"bode-{joint}.png", joint, responses,
                      [(f"identified (held-out Fit {result.heldout_fit_percent[0]:.1f} %)", result.params),
                       ("prior (rig file)", prior)], THESIS_BAND_HZ)
    overlay = plots.time_overlay(out / f"time-{joint}.png", joint, list(zip(labels, found))[::-1],
                                 [("identified", result.params), ("prior", prior)], result.settings["step_s"],
                                 C_SPAN * prior.Fs)
    name = f"{joint}-identified"
    provenance = (f"pneumactl identify {time.strftime('%Y-%m-%d %H:%M:%S')}: {Path(path).name} "
                  f"(rig {run.describe['rig']['hash'][:12]}), fitted on "
                  f"{', '.join(e.info['signal']['signal'] for e in estimation)}, held-out Fit "
                  f"{result.heldout_fit_percent[0]:.1f} % on the {held_out[0].info['signal']['signal']} "
                  f"(the prior's {prior_fit:.1f} %{'' if verdict is None else ': NOT BETTER'})")
    rig_text = rigfile.with_model(rig.source, joint, name, result.params, provenance, judged)
    rig_path = out / "rig.toml"
    rig_path.write_text(rig_text)
    coherent = responses[1][1].band(*THESIS_BAND_HZ).coherence if len(responses) > 1 else []
    report = {"joint": joint, "model": name, "rig_file": str(rig_path), "recording": str(path),
              "figures": [str(bode), str(overlay)], **result.summary(),
              "prior_heldout_fit_percent": prior_fit, "beats_prior": verdict is None, "warning": verdict,
              "judged": judged,
              "prior": {n: getattr(prior, n) for n in FITTED}, "units": {n: UNITS[n] for n in FITTED},
              "experiments": [e.info["signal"] for e in found],
              "time_base": [e.info["time_base"] for e in found],
              "coherence_thesis_band": {"min": float(min(coherent)) if len(coherent) else None,
                                        "mean": float(sum(coherent) / len(coherent)) if len(coherent) else None}}
    (out / "report.json").write_text(json.dumps(report, indent=2))
    print_table(report)
    return report


def _fit_progress(generations: int):
    last = [0.0]

    def show(generation: int, cost: float) -> None:
        if time.monotonic() - last[0] >= 2.0:
            last[0] = time.monotonic()
            print(f"fit: generation {generation} of at most {generations}, cost {cost:.4g}", file=sys.stderr, flush=True)
    return show
