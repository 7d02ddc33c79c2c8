"""Telemetry: what the loop publishes, as msgpack on ZeroMQ PUB topics.

- ``state``: every cycle, batched (``batch`` cycles a message), columns named with units;
  ``shadow_u_volts`` is what a shadow-run candidate would have commanded (None without one);
- ``stats``: once a second, loop timing (latency and per-stage compute percentiles, overruns),
  summarised beside the loop from its histograms (:mod:`daemon.wire.loop_stats`);
- ``event``: state changes, trips, controller switches, at once;
- ``internals``: the active controller's internal signals (its ``describe`` names them, e.g.
  SMC's sigma, the DOB's d_hat), one sample per ``state`` batch while the arm is enabled;
- ``contact``: with an array pressure sensor (the rig file's ``[contact_sensor]``), its
  latest contact estimate, its frame's time and age, once per ``state`` batch.
Both are sampled half a batch away from the batch's flush, so no cycle carries the two costs
(which is where a p99 of the cycle's compute time lives: one cycle in ten).
Every message carries a per-topic ``seq`` so a subscriber can count what it missed.

The loop does not serialise ``state``: :class:`Telemetry` packs each cycle's numbers into a
fixed binary row (one ``struct`` call) and hands a batch of rows to ``send``; the messenger
process (:mod:`daemon.messenger.process`) turns it into the msgpack message with
:func:`daemon.wire.telemetry_rows.to_payload`.
``internals`` is packed the same way, as numbers behind the controller's layout. The rare
``event`` messages are packed by the loop and passed on as they are; a ``stats``
window is a small binary message that the messenger turns into percentiles.
Sending never blocks: whatever ``send`` cannot take at once is dropped, never waited for.
"""
from __future__ import annotations

import math

import msgpack

from daemon.wire.telemetry_rows import (
    HEADER,
    INTERNALS_HEADER,
    MODE_INDEX,
    internals_layout,
    internals_values,
    row_format,
)


class Telemetry:
    def __init__(self, send, batch: int = 10):
        """``send(topic: bytes, body: bytes)`` must not block."""
        self._send = send
        self.batch = batch
        self.seq = {b"state": 0, b"event": 0, b"internals": 0, b"contact": 0}  # stats: numbered by its window
        self._shape: tuple[int, int] | None = None
        self._rows = 0
        self._buf = bytearray()
        self._internals_of = None  # the controller whose internals layout is packed in _layout
        self._layout = b""
        self._beside_flush = max(batch // 2, 1)  # the cycle of each batch that samples internals and contact

    def record(self, loop) -> None:
        """Pack this cycle's row into the batch; send the batch when it is full."""
        if self._shape is None:
            self._start(loop.n, len(loop.io.last_volts), len(loop.u))
        snap = loop.snapshot
        shadow_u = loop.shadow_run.u if loop.shadow_run is not None else None
        self._row.pack_into(self._buf, HEADER.size + self._rows * self._row.size, loop.cycle,
                            snap.t if snap is not None else loop.clock.now(), *loop.angles, *loop.velocities,
                            *loop.reference[0], *loop.u, *loop.p_head, *loop.p_rod, *loop.io.last_volts,
                            loop.force, MODE_INDEX[loop.supervisor.state], shadow_u is not None,
                            *(shadow_u if shadow_u is not None else self._no_shadow))
        self._rows += 1
        if self._rows >= self.batch:
            self.flush()
        elif self._rows == self._beside_flush:  # half a batch from the flush: the two costs never share a cycle
            if loop.supervisor.enabled and loop.controller.internals:
                self.internals(loop)
            if loop.contact_sensor is not None:
                self.contact(loop)

    def internals(self, loop) -> None:
        """One sample of the active controller's internal signals (decimated: a few dozen
        numbers once a batch), packed as numbers behind the controller's layout (packed once per
        controller); the messenger makes the message. A plugin whose signals cannot be read, or
        do not match its ``internals``, publishes none."""
        controller = loop.controller
        if controller is not self._internals_of:
            self._internals_of = controller
            self._layout = internals_layout(controller.name, [spec.name for spec in controller.internals])
        try:
            values = controller.internal_signals()
            rows, cols = len(values), len(values[0]) if values else 0
            if rows != len(controller.internals) or any(len(row) != cols for row in values):
                return
            numbers = internals_values(rows * cols).pack(*[v for row in values for v in row])
        except Exception:  # a plugin's failure must never take the loop down
            return
        self.seq[b"internals"] += 1
        self._send(b"internals", INTERNALS_HEADER.pack(self.seq[b"internals"], loop.cycle, loop.clock.now(),
                                                       len(self._layout), rows, cols) + self._layout + numbers)

    def contact(self, loop) -> None:
        """The array sensor's latest estimate (a dozen numbers; nothing before its first frame)."""
        latest = loop.contact_sensor.latest()
        if latest is not None:
            self._publish(b"contact", {"cycle": loop.cycle, "t": loop.clock.now(), **latest})

    def _start(self, n: int, m: int, k: int) -> None:
        self._shape = (n, m, k)
        self._row = row_format(n, m, k)
        self._no_shadow = (math.nan,) * k
        self._buf = bytearray(HEADER.size + self.batch * self._row.size)

    def flush(self) -> None:
        if not self._rows:
            return
        self.seq[b"state"] += 1
        HEADER.pack_into(self._buf, 0, self.seq[b"state"], *self._shape, self._rows)
        body = bytes(self._buf[:HEADER.size + self._rows * self._row.size])
        self._rows = 0
        self._send(b"state", body)

    def event(self, loop, event: dict) -> None:
        self._publish(b"event", {"cycle": loop.cycle, "t": loop.clock.now(), **event})

    def stats(self, window: bytes) -> None:
        """A closed stats window (:mod:`daemon.wire.loop_stats`), summarised beside the loop."""
        self._send(b"stats", window)

    def _publish(self, topic: bytes, message: dict) -> None:
        self.seq[topic] += 1
        message["seq"] = self.seq[topic]
        self._send(topic, msgpack.packb(message))
