"""The rig's experiments as Bluesky plans: a step response, a path, the identification
experiments and the payload routine's dithers. Each is one run: the rig's readings before
and after (stream ``primary``), each reference recorded by the daemon at 1 kHz and added as
HDF5 (streams ``record``, ``record_1`` ...: :mod:`daemon.client.bluesky.record`), and the
run's metadata: the rig's name and file hash, the controller and its parameters, the plan's
own arguments. The rig is staged for the run (lease taken, arm enabled) and unstaged after.

Each plan's ``rig`` is a :class:`~daemon.client.bluesky.device.PneumadRig` (left unannotated: a
queue item names it, and bluesky-queueserver turns the name into the device).

A refused command fails the plan with the daemon's RemoteError (code, message, data); a trip
while it runs, with the daemon's cause. Nothing here runs in the loop: the daemon plans each
reference beside it, as for any client.
"""
from __future__ import annotations

import json
import math

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp

from controllers.identification.data import prior_of
from daemon.client import identify, payload_routine
from daemon.client.bluesky.device import PneumadRig
from daemon.client.bluesky.record import DaemonRecord, Flight
from hal import config


def _metadata(rig: PneumadRig, plan: str, arguments: dict):
    """The run's start document's extras: what ran, on which rig file, under which controller."""
    controller = yield from bps.rd(rig.controller)
    params = yield from bps.rd(rig.controller_params)
    describe = rig.link.describe
    return {"plan_name": plan, "plan_args": arguments, "rig": describe["rig"]["name"],
            "rig_hash": describe["rig"]["hash"], "controller": controller,
            "controller_params": json.loads(params).get("params", {}), "pneumad_version": describe["version"]}


def _recorded(rig: PneumadRig, flights, md: dict):
    """Stage the rig, open the run, read it, fly and collect each flight into a stream of its
    own (HDF5 in the rig's ``hdf5_directory``), read it again."""
    record = DaemonRecord(rig, rig.hdf5_directory)
    @bpp.stage_decorator([rig])
    @bpp.run_decorator(md=md)
    def run():
        yield from bps.declare_stream(rig, name="primary")
        yield from bps.trigger_and_read([rig], name="primary")
        for k, flight in enumerate(flights):
            stream = "record" if k == 0 else f"record_{k}"
            yield from bps.prepare(record, flight, wait=True)
            yield from bps.declare_stream(record, name=stream, collect=True)
            yield from bps.checkpoint()  # a trip during the flight: a suspender flies it again from here
            yield from bps.kickoff(record, wait=True)
            yield from bps.complete(record, wait=True)
            yield from bps.collect(record, name=stream)
        yield from bps.trigger_and_read([rig], name="primary")
    return (yield from run())


def step_response(rig, joint: str, step: float, md: dict | None = None):
    """A step of ``step`` [the joint's display unit: deg on a rotary joint, mm on a linear one]
    on ``joint`` from its set-point, recorded until it has settled."""
    layout = rig.link.layout
    names = layout.owners()
    if joint not in names:
        raise ValueError(f"{rig.link.rig_name} has no joint {joint!r} (joints: {', '.join(names)})")
    field = layout[f"{joint}.setpoint"]
    target = {}

    targets: list[float] = []  # [display units], from the set-points at the first flight: a flight
    #                             flown again after a trip (a suspender) steps to the same target

    def send(client):
        if not targets:
            here = client.sample()  # the set-points [SI] as the latest cycle record has them
            targets.extend(here[f"{n}.setpoint"] * layout[f"{n}.position"].display[1] for n in names)
            targets[names.index(joint)] += step
            target[joint] = targets[names.index(joint)]
        return client.set(positions=targets, duration_s=0.0, record=True)

    meta = yield from _metadata(rig, "step_response", {"joint": joint, "step": step, "unit": field.display[0]})
    flight = Flight(send, settle=lambda reply: dict(target))
    return (yield from _recorded(rig, [flight], {**meta, **(md or {})}))


def path_run(rig, name: str, duration_s: float | None = None,
             md: dict | None = None):
    """One of the rig's paths (``translation``, ``circle``), approach included, recorded."""
    meta = yield from _metadata(rig, "path_run", {"name": name, "duration_s": duration_s})
    flight = Flight(lambda c: c.path(name, duration_s=duration_s, record=True))
    return (yield from _recorded(rig, [flight], {**meta, **(md or {})}))


def identification(rig, joint: str, quick: bool = True, experiments: list[dict] | None = None,
                   md: dict | None = None):
    """``pneumactl identify``'s experiments on ``joint`` (V_MV side, amplitude as it chooses
    it, fitted to the daemon's limits), each recorded into a stream of its own; the fit is
    ``pneumactl identify --from`` on the HDF5's recordings, or the notebook's. ``experiments``
    (instead of the plan's, e.g. one more chirp): each ``{"signal": ..., <excite's settings>}``,
    as ``excite`` takes them (docs/protocol.md)."""
    describe = rig.link.describe
    names = rig.link.layout.owners()
    if joint not in names:
        raise ValueError(f"{rig.link.rig_name} has no joint {joint!r} (joints: {', '.join(names)})")
    rig_config = config.parse(describe["rig"]["source"], "<daemon>")
    prior = prior_of(rig_config, joint)
    plan = identify.Plan.of(quick)
    if experiments is not None:
        plan = identify.Plan(tuple((e["signal"], {k: v for k, v in e.items() if k != "signal"}) for e in experiments),
                             plan.settle_s)
    u_range = identify.v_mv_range(describe, joint)

    def experiment(signal: str, settings: dict) -> Flight:
        def send(client):
            u_op = identify.holding_volts(rig_config, joint, math.degrees(client.sample()[f"{joint}.setpoint"]))
            args = {**settings, "settle_s": plan.settle_s}
            return identify.excite_fitting(lambda volts: client.excite_input(signal, joint, volts, record=True, **args),
                                           signal, identify.default_amplitude(prior, u_op, u_range), fixed=False)
        return Flight(send)

    meta = yield from _metadata(rig, "identification", {"joint": joint, "quick": quick, "experiments": experiments})
    flights = [experiment(signal, settings) for signal, settings in plan.experiments]
    # The whole plan also in one daemon recording, as `pneumactl identify` records it: the run's
    # start document names its file, which `pneumactl identify JOINT --from FILE` fits.
    (started,) = yield from bps.wait_for([lambda: rig.link.call("record_start", f"identification-{joint}")])
    recording = started.result()

    def stop():
        yield from bps.wait_for([lambda: rig.link.call("record_stop", recording["name"])])
    return (yield from bpp.finalize_wrapper(
        _recorded(rig, flights, {**meta, "recording": recording["file"], **(md or {})}), stop()))


def payload_dithers(rig, postures: list[list[float]] | None = None, periods: int | None = None,
                    md: dict | None = None):
    """The payload routine's measurement: at each of its postures (or ``postures`` [deg], one
    angle a joint each), every joint dithered about its balance (the daemon's ``excite``), each
    dither recorded; the estimate is the routine's (:func:`daemon.client.payload_routine.window_mean`
    on the records). ``periods``: each dither's length in its 2 s periods, 1-100 (default the
    routine's 21, ``DITHER_S`` long); fewer average less of the friction away, and below 13 the
    routine's ``AVERAGED_S`` window does not fit: average over a shorter ``seconds``."""
    describe = rig.link.describe
    rig_config = config.parse(describe["rig"]["source"], "<daemon>")
    names = rig.link.layout.owners()
    postures = payload_routine.postures(rig_config) if postures is None else [list(map(float, p)) for p in postures]
    if any(len(p) != len(names) for p in postures):
        raise ValueError(f"a posture is one angle [deg] for each of {', '.join(names)}")
    if periods is not None and (isinstance(periods, bool) or not isinstance(periods, int) or not 1 <= periods <= 100):
        raise ValueError(f"periods is a whole number of dither periods, 1-100, not {periods!r}")
    lengthen = {} if periods is None else {"periods": periods}
    flights = []
    for target in postures:
        flights.append(Flight(lambda c, t=target: c.set(angles_deg=t, duration_s=identify.move_duration(
            t, [math.degrees(c.sample()[f"{n}.setpoint"]) for n in names]), record=True),
            settle=lambda reply: dict(zip(names, reply["target_deg"]))))
        for name in names:
            flights.append(Flight(lambda c, n=name: c.call("excite", {**payload_routine.dither_args(rig_config, n),
                                                                       **lengthen, "record": True})))
    meta = yield from _metadata(rig, "payload_dithers", {"postures": postures, "periods": periods})
    return (yield from _recorded(rig, flights, {**meta, **(md or {})}))
