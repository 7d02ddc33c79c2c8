"""The ``state`` topic's binary batches: the loop packs one cycle record a row
(:mod:`daemon.loop.telemetry`, with the cycle layout's ``row``), the messenger turns a batch into
the msgpack columns subscribers see (docs/protocol.md, "The cycle record"). Both sides read the
batch's framing from here and its rows through :class:`daemon.wire.cycle_layout.CycleLayout`."""
from __future__ import annotations

import functools
import struct

import msgpack

from daemon.wire.cycle_layout import CycleLayout

# the ``contact`` topic's estimate: centre, semi-axes, peak pressure, shape, force, each with its 1 sigma;
# the track's age in estimated frames
CONTACT_FIELDS = ("cx", "cy", "a", "b", "p_max", "beta", "force_n", "area_m2", "taxels", "residual", "track_frames",
                  "cx_sd", "cy_sd", "a_sd", "b_sd", "p_max_sd", "beta_sd", "force_sd_n")
# A state batch: seq, the layout's id, the count of rows; then the rows (CycleLayout.row each).
HEADER = struct.Struct("<QIH")


class LayoutMismatch(ValueError):
    """A batch packed on a layout other than the reader's."""


def state_message(layout: CycleLayout, body: bytes) -> dict:
    """The ``state`` message of a batch from :class:`daemon.loop.telemetry.Telemetry`:
    ``{"seq", "layout", **layout.columns(rows)}``, one column per field of the layout (built a
    column at a time: the messenger does it 100 times a second)."""
    seq, layout_id, count = HEADER.unpack_from(body)
    if layout_id != layout.id:
        raise LayoutMismatch(f"a state batch of layout {layout_id:#010x}, read on layout {layout.id:#010x}")
    row = layout.row
    rows = list(row.iter_unpack(body[HEADER.size:HEADER.size + count * row.size]))
    return {"seq": seq, "layout": layout_id, **layout.columns(rows)}


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


def to_payload(layout: CycleLayout, topic: bytes, body: bytes) -> bytes:
    """What goes out on the PUB socket for what the loop's telemetry sent."""
    if topic == b"state":
        return msgpack.packb(state_message(layout, body))
    if topic == b"internals":
        return msgpack.packb(internals_message(body))
    return body
