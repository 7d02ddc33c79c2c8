"""Telemetry: what the loop publishes, as msgpack on ZeroMQ PUB topics.

- ``state``: every cycle's record (:mod:`daemon.wire.cycle_layout`), batched (``batch`` cycles a
  message), one column per field of the layout;
- ``stats``: once a second, loop timing (latency and per-stage compute percentiles, overruns),
  summarised beside the loop from its histograms (:mod:`daemon.wire.loop_stats`);
- ``event``: state changes, trips, controller switches, at once;
- ``internals``: the active controller's internal signals (its ``describe`` names them, e.g.
  SMC's sigma, the DOB's d_hat), one sample per ``state`` batch while the arm is enabled;
- ``contact``: with an array pressure sensor (the rig file's ``[contact_sensor]``), its
  latest contact estimate, its frame's time and age, once per ``state`` batch.
The batch's flush, the internals sample and the sample's sending (with the contact
estimate) each have a cycle of their own in every batch (its 10th, 3rd and 6th), so no cycle
carries two of them: the cycles that carry them are where the p99 of the cycle's compute time
lives (docs/benchmarks.md, "The cycles that carry telemetry"). A sample carries the cycle and
time it was taken at.
Every message carries a per-topic ``seq`` so a subscriber can count what it missed.

The loop does not serialise ``state``: :class:`Telemetry` packs each cycle's record into a
binary row with the layout's ``row`` (one ``struct`` call) and hands a batch of rows, headed by
the layout's id, to ``send``; the messenger process (:mod:`daemon.messenger.process`), given the
layout when it was spawned, turns it into the msgpack message with
:func:`daemon.wire.telemetry_rows.state_message`.
``internals`` is packed the same way, as numbers behind the controller's layout. The rare
``event`` messages are packed by the loop and passed on as they are; a ``stats``
window is a small binary message that the messenger turns into percentiles.
Sending never blocks: whatever ``send`` cannot take at once is dropped, never waited for.
"""
from __future__ import annotations

from itertools import chain

import msgpack

from daemon.wire.cycle_layout import CycleLayout
from daemon.wire.telemetry_rows import (
    HEADER,
    INTERNALS_HEADER,
    internals_layout,
    internals_values,
)


class Telemetry:
    def __init__(self, send, layout: CycleLayout, batch: int = 10):
        """``send(topic: bytes, body)`` must not block, and must copy ``body`` (bytes-like) if it
        keeps it: a state batch and an internals sample are passed as views of buffers this
        object reuses, so the ring's put is their only copy. ``layout``: the cycle record's."""
        self._send = send
        self.batch = batch
        self.layout = layout
        self.seq = {b"state": 0, b"event": 0, b"internals": 0, b"contact": 0}  # stats: numbered by its window
        self._row = layout.row
        self._pack, self._size = layout.row.pack_into, layout.row.size
        self._rows = 0
        self._at = HEADER.size  # where the next row goes
        self._buf = bytearray(HEADER.size + batch * self._row.size)
        self._view = memoryview(self._buf)
        self._internals_of = None  # the controller whose internals buffer is ready (_internals_for)
        self._sampled: tuple[int, float] | None = None  # the cycle and time [s] of a sample not sent yet
        if batch < 3:
            raise ValueError(f"a state batch of {batch} cycles: at least 3 (the flush, the internals sample and "
                             f"its sending each take a cycle of their own)")
        self._sample_at, self._send_at = batch // 3, 2 * batch // 3  # rows 3 and 6 of a 10-cycle batch

    def record(self, loop) -> None:
        """Pack this cycle's record (``loop.record``, on the layout) into the batch; send the
        batch when it is full."""
        self._pack(self._buf, self._at, *loop.record)
        self._at += self._size
        self._rows += 1
        if self._rows >= self.batch:
            self.flush()
        elif self._rows == self._sample_at:
            if loop.supervisor.enabled and loop.controller.internals:
                self.sample_internals(loop)
        elif self._rows == self._send_at:
            if self._sampled is not None:
                self.send_internals()
            if loop.contact_sensor is not None:
                self.contact(loop)

    def sample_internals(self, loop) -> None:
        """Take one sample of the active controller's internal signals (decimated: a few dozen
        numbers once a batch): its values packed behind the controller's layout in a buffer
        made once per controller, its cycle and time kept for :meth:`send_internals`. A plugin
        whose signals cannot be read, or do not match its ``internals``, gives no sample."""
        self._sampled = None  # one not sent yet (a batch cut short by a flush) is replaced, or dropped if this fails
        controller = loop.controller
        if controller is not self._internals_of:
            self._internals_for(controller, loop.n)
        rows, cols = self._internals_shape
        try:
            values = controller.internal_signals()
            if len(values) != rows:
                return
            for row in values:
                if len(row) != cols:
                    return
            self._internals_values.pack_into(self._internals_buf, self._internals_at, *chain.from_iterable(values))
        except Exception:  # a plugin's failure must never take the loop down
            return
        self._sampled = (loop.cycle, loop.clock.now())

    def send_internals(self) -> None:
        """Send the sample taken last, numbered now (so a sample that was never sent leaves no
        gap in ``seq``); the messenger makes the message."""
        cycle, t = self._sampled
        self._sampled = None
        self.seq[b"internals"] += 1
        INTERNALS_HEADER.pack_into(self._internals_buf, 0, self.seq[b"internals"], cycle, t, len(self._layout),
                                   *self._internals_shape)
        self._send(b"internals", self._internals_buf)

    def _internals_for(self, controller, n: int) -> None:
        """A sample's buffer for ``controller``: header, layout, one value per joint for each of
        its ``internals`` (the plugin contract, controllers.base)."""
        self._layout = internals_layout(controller.name, [spec.name for spec in controller.internals])
        self._internals_shape = rows, cols = len(controller.internals), n
        self._internals_values = internals_values(rows * cols)
        self._internals_at = INTERNALS_HEADER.size + len(self._layout)
        self._internals_buf = bytearray(self._internals_at + self._internals_values.size)
        self._internals_buf[INTERNALS_HEADER.size:self._internals_at] = self._layout
        self._internals_of = controller  # last: a build that raised is tried again, never half used

    def contact(self, loop) -> None:
        """The array sensor's latest estimate (a dozen numbers; nothing before its first frame)."""
        latest = loop.contact_sensor.latest()
        if latest is not None:
            self._publish(b"contact", {"cycle": loop.cycle, "t": loop.clock.now(), **latest})

    def flush(self) -> None:
        if not self._rows:
            return
        self.seq[b"state"] += 1
        HEADER.pack_into(self._buf, 0, self.seq[b"state"], self.layout.id, self._rows)
        size = HEADER.size + self._rows * self._row.size
        self._rows, self._at = 0, HEADER.size
        self._send(b"state", self._view[:size])

    def event(self, loop, event: dict) -> None:
        self._publish(b"event", {"cycle": loop.cycle, "t": loop.clock.now(), **event})

    def stats(self, window: bytes) -> None:
        """A closed stats window (:mod:`daemon.wire.loop_stats`), summarised beside the loop."""
        self._send(b"stats", window)

    def _publish(self, topic: bytes, message: dict) -> None:
        self.seq[topic] += 1
        message["seq"] = self.seq[topic]
        self._send(topic, msgpack.packb(message))
