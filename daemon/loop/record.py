"""Where the loop writes each group of its cycle record: the slices of the layout
(:class:`daemon.wire.cycle_layout.CycleLayout`) that hold the loop's own lists, found once when
the loop is built, so a cycle writes its record with a dozen slice assignments and never looks a
field up by name. A layout the loop cannot fill exactly (a group of the wrong size, a command
the actuation does not have) is refused here, before anything runs."""
from __future__ import annotations

import math
from typing import NamedTuple

from daemon.wire.cycle_layout import CycleLayout


class RecordSpans(NamedTuple):
    """The record's slices, in the loop's terms (each a ``slice`` of the record); a tuple, so a
    cycle takes them all with one unpacking."""

    position: slice  # the joints' positions [rad or m], in joint order (the loop's ``angles``)
    velocity: slice
    setpoint: slice
    error: slice  # set-point minus position
    command: slice  # the actuation's command vector (the loop's ``u``), in its order
    commanded_first: slice  # the first chamber's commanded pressure [Pa] of each joint that commands pressures
    commanded_second: slice
    pressure_joints: tuple[int, ...] | None  # those joints' indices; None: every joint (the slice takes the list)
    sensors: slice  # every sensor besides the positions, in the snapshot's ``measured`` order [SI]
    outputs: slice  # the output sweep as written [V]
    shadow: slice  # a shadow-run candidate's commands
    mode: int
    no_commands: tuple[float, ...]  # NaN for each command: none is in force outside ``enabled``
    no_sensors: tuple[float, ...]  # NaN for each sensor: a cycle whose read failed

    @classmethod
    def of(cls, layout: CycleLayout, joints: int, commands: list[str], pressure_joints: list[int], sensors: int,
           outputs: int) -> "RecordSpans":
        """The spans of ``layout`` for a loop of ``joints`` joints, whose actuation commands
        ``commands`` (``<joint>.<name>`` each, in its vector's order) and the chamber pressures of
        ``pressure_joints``, whose snapshot measures ``sensors`` values and whose transport
        writes ``outputs`` channels."""
        def span(group: str, size: int, quantity: str | None = None) -> slice:
            start, stop = layout.span(group, quantity)
            if stop - start != size:
                raise ValueError(f"cycle layout: {group} {quantity or ''} has {stop - start} fields, the loop "
                                 f"writes {size}")
            return slice(start, stop)

        command = span("command", len(commands))
        declared = [f"{f.owner}.{f.quantity[2:]}" for f in layout.fields[command]]
        if declared != commands:
            raise ValueError(f"cycle layout: commands {declared}, the actuation's {commands}")
        commanded = span("commanded", 2 * len(pressure_joints))
        half = commanded.start + len(pressure_joints)
        found = [f.index for f in layout.fields if f.group == "measured" and f.quantity not in ("position", "velocity")]
        start = found[0] if found else 0
        if found != list(range(start, start + len(found))):
            raise ValueError("cycle layout: the sensors are not one contiguous span")
        if len(found) != sensors:
            raise ValueError(f"cycle layout: {len(found)} sensors, the snapshot measures {sensors}")
        return cls(span("measured", joints, "position"), span("measured", joints, "velocity"),
                   span("reference", joints, "setpoint"), span("reference", joints, "error"), command,
                   slice(commanded.start, half), slice(half, commanded.stop),
                   None if pressure_joints == list(range(joints)) else tuple(pressure_joints),
                   slice(start, start + sensors), span("output", outputs), span("shadow", len(commands)),
                   layout["mode"].index, (math.nan,) * len(commands), (math.nan,) * sensors)
