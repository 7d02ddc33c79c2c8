"""Telemetry: what the loop publishes, as msgpack on ZeroMQ PUB topics.

- ``state``: every cycle, batched (``batch`` cycles a message), columns named with units;
  ``shadow_u_volts`` is what a shadow-run candidate would have commanded (None without one);
- ``stats``: once a second, loop timing (latency and per-stage compute percentiles, overruns);
- ``event``: state changes, trips, controller switches, at once;
- ``internals``: the active controller's internal signals (its ``describe`` names them, e.g.
  SMC's sigma, the DOB's d_hat), one sample per ``state`` batch while the arm is enabled;
- ``contact``: with an array pressure sensor (the rig file's ``[contact_sensor]``), its
  latest contact estimate, its frame's time and age, once per ``state`` batch.
Every message carries a per-topic ``seq`` so a subscriber can count what it missed.

The loop does not serialise ``state``: :class:`Telemetry` packs each cycle's numbers into a
fixed binary row (one ``struct`` call) and hands a batch of rows to ``send``; the messenger
process (:mod:`daemon.messenger`) turns it into the msgpack message with :func:`to_payload`.
The rare ``event`` and ``stats`` messages are packed by the loop and passed on as they are.
Sending never blocks: whatever ``send`` cannot take at once is dropped, never waited for.
"""
from __future__ import annotations

import functools
import math
import struct

import msgpack

from daemon.safety import State

STATE_FIELDS = ("cycle", "t", "angle_rad", "velocity_rad_s", "setpoint_rad", "error_rad", "u_volts",
                "p_head_pa", "p_rod_pa", "out_volts", "force_n", "mode", "shadow_u_volts")
MODES = tuple(s.value for s in State)
_MODE_INDEX = {s: i for i, s in enumerate(State)}
# A state batch: seq, joints n, outputs m, commands k, rows; then the rows (see _row_format).
_HEADER = struct.Struct("<QHHHH")


@functools.lru_cache(maxsize=8)
def _row_format(n: int, m: int, k: int) -> struct.Struct:
    """One cycle: cycle, t [s]; angle, velocity, set-point [rad, rad/s, rad] per joint; the k
    commands u (V_MV [V] per cylinder joint; a muscle pair's pressures [Pa] and brake [N m]);
    p_head, p_rod [Pa] per joint (the pressure pair: a muscle pair's a and b); out volts per
    output [V]; force [N]; mode index; shadow flag; shadow u per command (NaN without a shadow run)."""
    return struct.Struct(f"<qd{5 * n + k + m + 1}dBB{k}d")


class Telemetry:
    def __init__(self, send, batch: int = 10):
        """``send(topic: bytes, body: bytes)`` must not block."""
        self._send = send
        self.batch = batch
        self.seq = {b"state": 0, b"stats": 0, b"event": 0, b"internals": 0, b"contact": 0}
        self._shape: tuple[int, int] | None = None
        self._rows = 0
        self._buf = bytearray()

    def record(self, loop) -> None:
        """Pack this cycle's row into the batch; send the batch when it is full."""
        if self._shape is None:
            self._start(loop.n, len(loop.io.last_volts), len(loop.u))
        snap = loop.snapshot
        shadow_u = loop.shadow.u if loop.shadow is not None else None
        self._row.pack_into(self._buf, _HEADER.size + self._rows * self._row.size, loop.cycle,
                            snap.t if snap is not None else loop.clock.now(), *loop.angles, *loop.velocities,
                            *loop.reference[0], *loop.u, *loop.p_head, *loop.p_rod, *loop.io.last_volts,
                            loop.force, _MODE_INDEX[loop.supervisor.state], shadow_u is not None,
                            *(shadow_u if shadow_u is not None else self._no_shadow))
        self._rows += 1
        if self._rows >= self.batch:
            self.flush()
            if loop.supervisor.enabled and loop.controller.internals:
                self.internals(loop)
            if loop.contact_sensor is not None:
                self.contact(loop)

    def internals(self, loop) -> None:
        """One sample of the active controller's internal signals (decimated: a few dozen
        numbers once a batch). A plugin whose signals cannot be read publishes none."""
        controller = loop.controller
        try:
            values = [[float(v) for v in row] for row in controller.internal_signals()]
        except Exception:  # a plugin's failure must never take the loop down
            return
        self._publish(b"internals", {"cycle": loop.cycle, "t": loop.clock.now(), "controller": controller.name,
                                     "signals": {spec.name: row for spec, row in zip(controller.internals, values)}})

    def contact(self, loop) -> None:
        """The array sensor's latest estimate (a dozen numbers; nothing before its first frame)."""
        latest = loop.contact_sensor.latest()
        if latest is not None:
            self._publish(b"contact", {"cycle": loop.cycle, "t": loop.clock.now(), **latest})

    def _start(self, n: int, m: int, k: int) -> None:
        self._shape = (n, m, k)
        self._row = _row_format(n, m, k)
        self._no_shadow = (math.nan,) * k
        self._buf = bytearray(_HEADER.size + self.batch * self._row.size)

    def flush(self) -> None:
        if not self._rows:
            return
        self.seq[b"state"] += 1
        _HEADER.pack_into(self._buf, 0, self.seq[b"state"], *self._shape, self._rows)
        body = bytes(self._buf[:_HEADER.size + self._rows * self._row.size])
        self._rows = 0
        self._send(b"state", body)

    def event(self, loop, event: dict) -> None:
        self._publish(b"event", {"cycle": loop.cycle, "t": loop.clock.now(), **event})

    def stats(self, summary: dict) -> None:
        self._publish(b"stats", summary)

    def _publish(self, topic: bytes, message: dict) -> None:
        self.seq[topic] += 1
        message["seq"] = self.seq[topic]
        self._send(topic, msgpack.packb(message))


def state_message(body: bytes) -> dict:
    """The ``state`` message (columns, as subscribers see it) of a batch from :class:`Telemetry`."""
    seq, n, m, k, count = _HEADER.unpack_from(body)
    row = _row_format(n, m, k)
    columns: dict[str, list] = {name: [] for name in STATE_FIELDS}
    for r in row.iter_unpack(body[_HEADER.size:_HEADER.size + count * row.size]):
        q, w, ref = (list(r[2 + i * n:2 + (i + 1) * n]) for i in range(3))
        u = list(r[2 + 3 * n:2 + 3 * n + k])
        ph, pr = list(r[2 + 3 * n + k:2 + 4 * n + k]), list(r[2 + 4 * n + k:2 + 5 * n + k])
        rest = r[2 + 5 * n + k:]
        columns["cycle"].append(r[0])
        columns["t"].append(r[1])
        columns["angle_rad"].append(q)
        columns["velocity_rad_s"].append(w)
        columns["setpoint_rad"].append(ref)
        columns["error_rad"].append([a - b for a, b in zip(ref, q)])
        columns["u_volts"].append(u)
        columns["p_head_pa"].append(ph)
        columns["p_rod_pa"].append(pr)
        columns["out_volts"].append(list(rest[:m]))
        columns["force_n"].append(rest[m])
        columns["mode"].append(MODES[rest[m + 1]])
        columns["shadow_u_volts"].append(list(rest[m + 3:]) if rest[m + 2] else None)
    columns["seq"] = seq
    return columns


def to_payload(topic: bytes, body: bytes) -> bytes:
    """What goes out on the PUB socket for what :class:`Telemetry` sent."""
    return msgpack.packb(state_message(body)) if topic == b"state" else body
