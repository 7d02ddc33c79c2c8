"""Every command of docs/protocol.md, accepted and refused, with its largest allowed arguments:
the catalogue that the proof test (tests/test_every_command.py) and the stall bench
(bench/command_stall.py) send to a real daemon on the built-in simulated 2-joint rig.

Each case names the state it needs (:func:`prepare` puts the daemon there first, unmeasured)
and the reply it must get: ``None`` for a result, else the error code.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from daemon.wire import protocol as P
from daemon.client.client import Client, RemoteError

MAX_POINTS = 1000  # waypoints and step levels (docs/protocol.md)
MAX_S = 3600.0  # the longest duration, hold or segment [s]


@dataclass(frozen=True)
class Case:
    label: str
    cmd: str
    args: dict = field(default_factory=dict)
    expect: str | None = None  # None: a result; else the error code
    needs: str = "enabled"  # the state prepare() sets up: enabled, idle, estop, pid, shadow, loaded
    control: bool = False  # sent on the control socket


def _joint_points(n: int) -> list[list[float]]:
    """n joint waypoints [deg] about (130, -75): the bottom joint swings +-5 deg."""
    return [[130.0 + 5.0 * math.sin(i), -75.0 + 0.5 * math.cos(i)] for i in range(n)]


def _tip_points(n: int) -> list[list[float]]:
    """n tip waypoints [mm] on a 15 mm circle about (50, 138)."""
    return [[50.0 + 15.0 * math.cos(0.1 * i), 138.0 + 15.0 * math.sin(0.1 * i)] for i in range(n)]


def _lti_design(order: int) -> dict:
    """A stable continuous SISO design of the largest order per joint (a PI with fast poles)."""
    joint = {"input": "error_deg", "dt": 0.0, "method": "bilinear",
             "A": [[-(10.0 + k) if k == j else 0.0 for k in range(order)] for j in range(order)],
             "B": [[1.0] for _ in range(order)], "C": [[0.01 for _ in range(order)]], "D": [[0.5]]}
    return {"joints": {"bottom": joint, "middle": joint}}


CASES: list[Case] = [
    Case("ping", "ping", needs="any"),
    Case("status", "status", needs="any"),
    Case("describe", "describe", needs="any"),
    Case("ping, unknown argument", "ping", {"x": 1}, P.BAD_ARGS, needs="any"),
    Case("unknown command", "self_destruct", {}, P.UNKNOWN_COMMAND, needs="any"),
    Case("lease.renew", "lease.renew", needs="any"),
    Case("lease.acquire, held", "lease.acquire", {}, P.LEASE_HELD, needs="any"),
    Case("controller.list", "controller.list", needs="any"),
    Case("controller.get", "controller.get", needs="any"),
    Case("enable", "enable", needs="idle"),
    Case("enable, enabled", "enable", {}, P.BAD_STATE),
    Case("disable", "disable"),
    Case("disable (control)", "disable", control=True),
    Case("abort (control)", "abort", control=True),
    Case("estop (control)", "estop", {"who": "bench"}, control=True),
    Case("reset", "reset", needs="estop"),
    Case("set, 3600 s", "set", {"angles_deg": [130.0, -75.0], "duration_s": MAX_S}),
    Case("set, 0.04 s: too fast", "set", {"angles_deg": [155.0, -100.0], "duration_s": 0.04}, P.REFUSED),
    Case("set, out of reach", "set", {"xy_mm": [500.0, 0.0], "duration_s": 10.0}, P.REFUSED),
    Case("set, a stiffness for cylinder joints", "set", {"angles_deg": [130.0, -75.0], "stiffness_nm_deg": [0.5, 0.5]},
         P.BAD_ARGS),
    Case("path circle, 3600 s", "path", {"name": "circle", "duration_s": MAX_S, "approach_s": 600.0}),
    Case("path circle, 5 s: too fast", "path", {"name": "circle", "duration_s": 5.0}, P.REFUSED),
    Case("path translation, 1e-9 s approach", "path", {"name": "translation", "approach_s": 1e-9}, P.REFUSED),
    Case("waypoints, 1000 joint points x 3600 s", "waypoints",
         {"angles_deg": _joint_points(MAX_POINTS), "durations_s": [MAX_S] * (MAX_POINTS - 1)}),
    Case("waypoints, 1000 tip points x 0.01 s: too fast", "waypoints",
         {"xy_mm": _tip_points(MAX_POINTS), "durations_s": [0.01] * (MAX_POINTS - 1)}, P.REFUSED),
    Case("steps, 1000 levels x 3600 s", "steps",
         {"angles_deg": _joint_points(MAX_POINTS), "hold_s": [MAX_S] * MAX_POINTS}),
    Case("steps, 1000 levels, the last beyond the limits", "steps",
         {"angles_deg": _joint_points(MAX_POINTS - 1) + [[180.0, -75.0]], "hold_s": [MAX_S] * MAX_POINTS},
         P.REFUSED),
    Case("excite prbs, order 16 x 60 s x 100: longer than 3600 s", "excite",
         {"signal": "prbs", "joint": "bottom", "amplitude_deg": 0.5, "order": 16, "bit_s": 60.0, "periods": 100},
         P.BAD_ARGS),
    Case("excite prbs, order 16 x 0.05 s", "excite",
         {"signal": "prbs", "joint": "bottom", "amplitude_deg": 0.5, "order": 16, "bit_s": 0.05, "periods": 1}),
    Case("excite chirp, 100 Hz x 3600 s: beyond the rig", "excite",
         {"signal": "chirp", "joint": "middle", "amplitude_deg": 10.0, "f0_hz": 0.001, "f1_hz": 100.0,
          "duration_s": MAX_S}, P.REFUSED),
    Case("excite input multisine, 32 x 600 s", "excite",
         {"side": "input", "signal": "multisine", "joint": "bottom", "amplitude_v": 0.3, "f0_hz": 0.05, "f1_hz": 100.0,
          "components": 32, "period_s": 600.0, "periods": 1, "settle_s": 60.0, "band_deg": 10.0}),
    Case("excite input steps, 256 levels: beyond the band", "excite",
         {"side": "input", "signal": "steps", "joint": "bottom", "amplitude_v": 2.0,
          "levels": [1.0 if i % 2 else -1.0 for i in range(255)] + [1.0], "hold_s": 2.3}, P.REFUSED),
    Case("excite input prbs, order 16: longer than 600 s", "excite",
         {"side": "input", "signal": "prbs", "joint": "bottom", "amplitude_v": 1.0, "order": 16, "bit_s": 60.0,
          "periods": 100}, P.BAD_ARGS),
    Case("motion while disabled", "set", {"angles_deg": [130.0, -75.0], "duration_s": 10.0}, P.BAD_STATE,
         needs="idle"),
    Case("controller.switch lti, order 32", "controller.switch", {"name": "lti", "options": {"design": _lti_design(32)}}),
    Case("controller.switch, unknown", "controller.switch", {"name": "nope"}, P.BAD_ARGS),
    Case("controller.set", "controller.set", {"params": {"Kp": [50.0, 55.0]}}, needs="pid"),
    Case("controller.set, out of range", "controller.set", {"params": {"Kp": [1e9, 55.0]}}, P.BAD_ARGS, needs="pid"),
    Case("controller.shadow smc_dob", "controller.shadow", {"name": "smc_dob"}, needs="pid"),
    Case("controller.commit", "controller.commit", needs="shadow"),
    Case("controller.discard", "controller.discard", needs="shadow"),
    Case("controller.commit, no shadow", "controller.commit", {}, P.BAD_STATE, needs="pid"),
    Case("load.set, the heaviest the arm carries in every posture", "load.set",
         {"mass_kg": 0.25, "com_mm": [20.0, 0.0]}),
    Case("load.set, beyond the arm", "load.set", {"mass_kg": 1000.0, "com_mm": [500.0, 0.0]}, P.BAD_ARGS),
    Case("load.clear", "load.clear", needs="loaded"),
    Case("record.start, the longest name, 24 h", "record.start", {"name": "r" * 80, "seconds": 86400.0}, needs="any"),
    Case("record.start, a name with a path in it", "record.start", {"name": "../../etc/passwd"}, P.BAD_ARGS,
         needs="any"),
    Case("record.list", "record.list", needs="any"),
    Case("record.stop", "record.stop", needs="any"),
    Case("record.stop, nothing running", "record.stop", {}, P.BAD_STATE, needs="any"),
    Case("path translation, recorded", "path", {"name": "translation", "record": True}),
    Case("path, record not a boolean", "path", {"name": "translation", "record": "yes"}, P.BAD_ARGS),
]


def prepare(client: Client, case: Case) -> None:
    """Put the daemon in the state ``case`` needs (the client holds the lease)."""
    if case.needs == "any":
        return
    state = client.status()["state"]
    if state in ("fault", "estop"):
        client.reset()
        state = "idle"
    if case.needs == "estop":
        client.estop("prepare")
        return
    if case.needs == "idle":
        if state == "enabled":
            client.disable()
        return
    if state == "idle":
        client.enable()
    client.abort()
    if case.needs == "loaded":
        client.call("load.set", {"mass_kg": 0.1})
    elif client.status()["load"] is not None:  # a load fed forward would change what motion may do
        client.call("load.clear")
    if case.needs in ("pid", "shadow"):
        if client.controller()["name"] != "pid":
            client.switch_controller("pid")
        try:
            client.discard()
        except RemoteError:
            pass  # no shadow run
    if case.needs == "shadow":
        client.shadow("pid")


def send(client: Client, case: Case):
    """The case's request; its result, or the RemoteError it got."""
    try:
        return client.call(case.cmd, case.args, control=case.control)
    except RemoteError as exc:
        return exc
