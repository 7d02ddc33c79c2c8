"""Telemetry: what the loop publishes, as msgpack on ZeroMQ PUB topics.

- ``state``: every cycle, batched (``batch`` cycles a message), columns named with units;
  ``shadow_u_volts`` is what a shadow-run candidate would have commanded (None without one);
- ``stats``: once a second, loop timing (latency and per-stage compute percentiles, overruns);
- ``event``: state changes, trips, controller switches, at once.
Every message carries a per-topic ``seq`` so a subscriber can count what it missed. Sending
never blocks: the PUB socket's high-water mark drops messages for a subscriber that is
not keeping up, and the loop never waits for one.
"""
from __future__ import annotations

import msgpack

STATE_FIELDS = ("cycle", "t", "angle_rad", "velocity_rad_s", "setpoint_rad", "error_rad", "u_volts",
                "p_head_pa", "p_rod_pa", "out_volts", "force_n", "mode", "shadow_u_volts")


class Telemetry:
    def __init__(self, send, batch: int = 10):
        """``send(topic: bytes, payload: bytes)`` must not block."""
        self._send = send
        self.batch = batch
        self._rows: list[tuple] = []
        self.seq = {b"state": 0, b"stats": 0, b"event": 0}

    def record(self, loop) -> None:
        """Keep this cycle's row. Only angles and velocities are updated in place by the loop;
        the other lists are replaced every cycle, so they are kept without copying."""
        snap = loop.snapshot
        self._rows.append((loop.cycle, snap.t if snap is not None else loop.clock.now(), tuple(loop.angles),
                           tuple(loop.velocities), loop.reference[0], loop.u, loop.p_head, loop.p_rod,
                           loop.io.last_volts, loop.force, loop.supervisor.state.value,
                           loop.shadow.u if loop.shadow is not None else None))
        if len(self._rows) >= self.batch:
            self.flush()

    def flush(self) -> None:
        if not self._rows:
            return
        columns = [list(c) for c in zip(*self._rows)]
        self._rows.clear()
        errors = [[r - a for r, a in zip(ref, q)] for ref, q in zip(columns[4], columns[2])]
        columns.insert(5, errors)
        self._publish(b"state", dict(zip(STATE_FIELDS, columns)))

    def event(self, loop, event: dict) -> None:
        self._publish(b"event", {"cycle": loop.cycle, "t": loop.clock.now(), **event})

    def stats(self, summary: dict) -> None:
        self._publish(b"stats", summary)

    def _publish(self, topic: bytes, message: dict) -> None:
        self.seq[topic] += 1
        message["seq"] = self.seq[topic]
        self._send(topic, msgpack.packb(message))
