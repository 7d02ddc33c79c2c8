"""The ``state`` topic's binary rows: the loop packs one per cycle (:mod:`daemon.loop.telemetry`),
the messenger turns a batch of them into the msgpack columns subscribers see
(docs/protocol.md, "Telemetry"). Both sides read the layout from here."""
from __future__ import annotations

import functools
import struct

import msgpack

from daemon.wire.states import State

STATE_FIELDS = ("cycle", "t", "angle_rad", "velocity_rad_s", "setpoint_rad", "error_rad", "u_volts",
                "p_head_pa", "p_rod_pa", "out_volts", "force_n", "mode", "shadow_u_volts")
# the ``contact`` topic's estimate: centre, semi-axes, peak pressure, shape, force, each with its 1 sigma;
# the track's age in estimated frames
CONTACT_FIELDS = ("cx", "cy", "a", "b", "p_max", "beta", "force_n", "area_m2", "taxels", "residual", "track_frames",
                  "cx_sd", "cy_sd", "a_sd", "b_sd", "p_max_sd", "beta_sd", "force_sd_n")
MODES = tuple(s.value for s in State)
MODE_INDEX = {s: i for i, s in enumerate(State)}
# A state batch: seq, joints n, outputs m, commands k, rows; then the rows (see row_format).
HEADER = struct.Struct("<QHHHH")


@functools.lru_cache(maxsize=8)
def row_format(n: int, m: int, k: int) -> struct.Struct:
    """One cycle: cycle, t [s]; angle, velocity, set-point [rad, rad/s, rad] per joint; the k
    commands u (V_MV [V] per cylinder joint; a muscle pair's pressures [Pa] and brake [N m]);
    p_head, p_rod [Pa] per joint (the pressure pair: a muscle pair's a and b); out volts per
    output [V]; force [N]; mode index; shadow flag; shadow u per command (NaN without a shadow run)."""
    return struct.Struct(f"<qd{5 * n + k + m + 1}dBB{k}d")


def state_message(body: bytes) -> dict:
    """The ``state`` message (columns, as subscribers see it) of a batch from :class:`Telemetry`:
    built a column at a time (a quarter cheaper than row by row: the messenger does it 100 times
    a second, an in-process test for every batch it reads)."""
    seq, n, m, k, count = HEADER.unpack_from(body)
    row = row_format(n, m, k)
    rows = list(row.iter_unpack(body[HEADER.size:HEADER.size + count * row.size]))
    w, ref, u = 2 + n, 2 + 2 * n, 2 + 3 * n  # where each group of a row starts (see row_format)
    head = u + k
    rod, out = head + n, head + 2 * n
    force = out + m
    message = dict(zip(STATE_FIELDS, (
        [r[0] for r in rows], [r[1] for r in rows], [list(r[2:w]) for r in rows], [list(r[w:ref]) for r in rows],
        [list(r[ref:u]) for r in rows], [[a - b for a, b in zip(r[ref:u], r[2:w])] for r in rows],
        [list(r[u:head]) for r in rows], [list(r[head:rod]) for r in rows], [list(r[rod:out]) for r in rows],
        [list(r[out:force]) for r in rows], [r[force] for r in rows], [MODES[r[force + 1]] for r in rows],
        [list(r[force + 3:]) if r[force + 2] else None for r in rows])))
    message["seq"] = seq
    return message


# An internals sample: seq, cycle, t [s], the layout's length, signals, joints; then the layout
# (msgpack: the controller's name and its signals' names, packed once per controller) and the values.
INTERNALS_HEADER = struct.Struct("<QqdHHH")


def internals_layout(controller: str, signals: list[str]) -> bytes:
    return msgpack.packb([controller, signals])


@functools.lru_cache(maxsize=16)
def internals_values(count: int) -> struct.Struct:
    return struct.Struct(f"<{count}d")


def internals_message(body: bytes) -> dict:
    """The ``internals`` message (docs/protocol.md) of a sample from the loop's telemetry."""
    seq, cycle, t, size, rows, cols = INTERNALS_HEADER.unpack_from(body)
    start = INTERNALS_HEADER.size
    controller, names = msgpack.unpackb(body[start:start + size])
    if len(names) != rows:
        raise IndexError(f"{rows} rows of internals for {len(names)} signals")
    values = internals_values(rows * cols).unpack_from(body, start + size)
    return {"cycle": cycle, "t": t, "controller": controller,
            "signals": {name: list(values[i * cols:(i + 1) * cols]) for i, name in enumerate(names)}, "seq": seq}


def to_payload(topic: bytes, body: bytes) -> bytes:
    """What goes out on the PUB socket for what the loop's telemetry sent."""
    if topic == b"state":
        return msgpack.packb(state_message(body))
    if topic == b"internals":
        return msgpack.packb(internals_message(body))
    return body
