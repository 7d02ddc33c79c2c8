"""Drift on the simulated rig for the model beside the arm (docs/model.md): the built-in rig with
a drift from a time on (``[transport.options.joints.NAME]``, docs/simulator.md "Drift"), the
real loop on a virtual clock moving the arm back and forth through waypoints, and its state
messages fed to :class:`controllers.drift_watch.ModelWatch` as the model process feeds them."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from controllers.drift_watch import ModelWatch
from daemon.recordings.mcap_log import McapRecording
from daemon.testing.loop import dealer, make_loop, ok, run_seconds
from hal import config

REST = (141.8, -90.0)  # where the built-in rig's joints rest at the bias pressures [deg]
SWING = ((135.0, -95.0), (148.0, -85.0), REST)  # the waypoints the arm goes through in turn, 2 s apart
AXIS_REST = (100.0,)  # where the built-in axis (sim-axis) starts: mid-way between its limits [mm]
AXIS_SWING = ((60.0,), (140.0,), AXIS_REST)  # its waypoints, as SWING's
AXIS_DRIFTS = {"offset": "sensor_offset_mm = 2.0\noffset_ramp_s = 0.1"}  # 20 mm/s for 0.1 s
DRIFTS = {  # the four the tests inject, on the bottom joint
    "offset": "sensor_offset_deg = 2.0\noffset_ramp_s = 0.1",  # 20 deg/s for 0.1 s: under the speed limit
    "leak_head": 'leak = "head"\nleak_fraction = 0.1',
    "friction": "friction_scale = 2.0",
    "gain": "regulator_gain = 0.8",
}


def drifted_rig(drift: str = "", joint: str = "bottom", at_s: float = 8.0, base: str | None = None) -> str:
    """The built-in rig's text (or ``base``) with ``drift`` (TOML lines) on ``joint`` from ``at_s``."""
    text = base if base is not None else config.load().source
    if drift:
        table = f"\n[transport.options.joints.{joint}]\nfault_at_s = {at_s}\n{drift}\n"
        before = "\n[arm]\n" if "\n[arm]\n" in text else "\n[[joints]]\n"  # (a rig without an arm: the axis)
        text = text.replace(before, table + before, 1)
    return text


def axis_rig(drift: str = "", at_s: float = 8.0) -> str:
    """The built-in linear axis's rig (sim-axis) with ``drift`` on its axis from ``at_s``."""
    return drifted_rig(drift, "axis", at_s, config.load("sim-axis").source)


@dataclass
class Watched:
    """What the model said of a run: its ``model`` messages and verdicts (with the model's time)."""

    messages: list[dict] = field(default_factory=list)
    verdicts: list[tuple[float, object]] = field(default_factory=list)
    residuals: dict[str, list[float]] = field(default_factory=dict)
    times: list[float] = field(default_factory=list)


def swing(rig_text: str, seconds: float, period_s: float = 2.0, record: str | Path | None = None,
          feed: Callable[[dict], None] | None = None, behind: bool = False, axis: bool = False) -> list[dict]:
    """The loop on ``rig_text`` enabled, swinging through SWING (a waypoint each ``period_s``)
    for ``seconds`` of its virtual clock; its state messages (and, ``record``, an MCAP recording
    of all it published there, as the daemon's recorder writes one). ``feed``: each state message
    is handed to it a second at a time instead, and none kept (a long run). ``behind``: every
    third cycle wakes two periods late, the deadlines between skipped (a loaded PC's loop, at
    about 600 cycles a second). ``axis``: the rig is a linear axis, moved through AXIS_SWING by
    its PID (``axis_pid``)."""
    rest, path = (AXIS_REST, AXIS_SWING) if axis else (REST, SWING)
    loop, captured, server = make_loop(rig_text, server=True, controller="axis_pid" if axis else "pid")
    try:
        sock = dealer(server)
        describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60})["lease"]
        ok(loop, sock, "enable", lease=lease)
        points = [list(rest)] + [list(p) for p in path] * int(seconds / (period_s * len(path)) + 1)
        ok(loop, sock, "waypoints", {"positions" if axis else "angles_deg": points,
                                     "durations_s": [period_s] * (len(points) - 1)}, lease=lease)
        if feed is not None:
            left = int(round((seconds - loop.clock.now()) / loop.period))
            while left > 0:
                loop.run(min(left, 1000))
                left -= 1000
                for m in captured.drain("state"):
                    feed(m)
                ok(loop, sock, "lease.renew", lease=lease)  # the clock is virtual: the lease counts its seconds
            return []
        if behind:
            while loop.clock.now() < seconds:
                loop.run_at(loop.clock.now() + loop.period * (3 if loop.cycle % 3 == 0 else 1))
        else:
            run_seconds(loop, seconds - loop.clock.now())
        if record is not None:
            with open(record, "wb") as f:
                rec = McapRecording(f, describe, controller)
                for topic, message in captured.messages:
                    rec.write(topic, message)
                rec.finish()
        return captured.of("state")
    finally:
        loop.stop()
        server.close()


def watch(rig_text: str, states: list[dict], publish_hz: float | None = None) -> Watched:
    """``states`` fed to the model of ``rig_text``'s rig, judged at its ``publish_hz``."""
    rig = config.parse(rig_text)
    model = ModelWatch(rig)
    period = 1.0 / (publish_hz or rig.model_watch.publish_hz)
    out = Watched(residuals={name: [] for name in model.joints})
    due = -1.0
    for m in states:
        for name, r in model.feed(m).items():
            out.residuals[name] += r
        out.times += m["t"]
        if model.t >= due:
            due = model.t + period
            message, verdicts = model.judge()
            out.messages.append(message)
            out.verdicts += [(model.t, v) for v in verdicts]
    return out
