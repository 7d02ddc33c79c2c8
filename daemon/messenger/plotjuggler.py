"""Telemetry that PlotJuggler plots as it comes (``pneumad run --plotjuggler ENDPOINT``).

PlotJuggler's "ZMQ Subscriber" source parses each message with its msgpack parser, flattens
nested maps into series named by their path (``/middle/position_deg``) and, with "use field as
timestamp if available", takes each message's time from a field: so this PUB socket sends one
single-frame msgpack map per loop cycle (a row, not the ``state`` topic's 10-cycle columns),
each with its own ``t`` [s, the daemon's monotonic clock]; the controller's internals and the
loop's timing come as rows of their own. Single frames, no topic frame: PlotJuggler versions
that read one frame a message and those that take a topic frame first both parse them.

A row holds every field of the cycle record (:mod:`daemon.wire.cycle_layout`) but the clock
and the mode, each under its owner (a joint's name; the rig's own at the top) as
``<quantity>_<unit>`` in the unit a person reads it in (deg for rad, mm for m:
``/middle/position_deg``, ``/middle/p_head_cmd_Pa``, ``/force_N``); a field nobody wrote this
cycle (NaN) is left out of the row.

It runs in the messenger process, from the telemetry it already decoded; the loop never
knows. PlotJuggler cannot do CURVE, so the endpoint must be local (loopback or ipc; reach it
from a laptop through ``ssh -L``) unless the daemon runs ``--insecure``.
"""
from __future__ import annotations

import json
import os

import msgpack
import zmq

from daemon.wire.cycle_layout import CycleLayout

HWM = 20_000  # rows queued for a slow PlotJuggler before ZeroMQ drops (20 s)


class PlotJugglerFeed:
    def __init__(self, ctx: zmq.Context, endpoint: str, rings_dir: str, layout: CycleLayout):
        self.socket = ctx.socket(zmq.PUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SNDHWM, HWM)
        self.socket.bind(endpoint)
        self._rings_dir = rings_dir
        self._joints: list[str] | None = None
        # each plotted field: (name, owner, its key in the row, the scale to its display unit)
        self._series = [(f.name, f.owner, f"{f.quantity}_{_key(f.display[0])}", f.display[1]) for f in layout.fields
                        if f.group not in ("clock", "mode")]

    def joints(self, n: int) -> list[str]:
        """The joints' names from the daemon's describe (written at its start), else j0, j1 ..."""
        if self._joints is None or len(self._joints) != n:
            try:
                with open(os.path.join(self._rings_dir, "describe.json")) as f:
                    self._joints = [j["name"] for j in json.load(f)["joints"]]
            except (OSError, ValueError, KeyError, TypeError):
                self._joints = [f"j{i}" for i in range(n)]
        return self._joints if len(self._joints) == n else [f"j{i}" for i in range(n)]

    def state(self, columns: dict) -> None:
        """One row per cycle of a ``state`` message (:func:`daemon.wire.telemetry_rows.state_message`)."""
        series = [(columns[name], owner, key, scale) for name, owner, key, scale in self._series]
        for i, cycle in enumerate(columns["cycle"]):
            row = {"t": columns["t"][i], "cycle": cycle}
            for values, owner, key, scale in series:
                x = values[i]
                if x == x:
                    (row.setdefault(owner, {}) if owner else row)[key] = x * scale
            self._send(row)

    def internals(self, message: dict) -> None:
        signals = message.get("signals", {})
        n = len(next(iter(signals.values()), []))
        names = self.joints(n)
        self._send({"t": message["t"], "internals": {signal: dict(zip(names, values))
                                                     for signal, values in signals.items()}})

    def stats(self, message: dict) -> None:
        row = {"overruns": message.get("overruns", 0)}
        for figure in ("latency_us", "compute_us"):
            value = message.get(figure, {})
            if figure == "compute_us":
                value = value.get("total", {})
            row.update({f"{figure}_{k}": v for k, v in value.items() if k in ("p50", "p99", "max")})
        self._send({"t": message["t"], "stats": row})

    def _send(self, row: dict) -> None:
        try:
            self.socket.send(msgpack.packb(row), zmq.NOBLOCK)
        except zmq.Again:
            pass  # PUB drops at the high-water mark by itself; this is only belt and braces

    def close(self) -> None:
        self.socket.close()


def _key(unit: str) -> str:
    """A unit as part of a series' name: ``deg/s`` -> ``deg_s``, ``N m`` -> ``N_m``, ``-`` -> ``1``."""
    return unit.replace("/", "_").replace(" ", "_").replace("-", "1")
