"""The cycle record's layout: one declaration of every number the loop records each cycle,
built from the interfaces the rig declares (:mod:`hal.interfaces`), never listed by hand.

The loop writes one preallocated record (a flat list of floats, :meth:`CycleLayout.record`)
each cycle; the telemetry row is that record packed with one ``struct`` call; the ``state``
message, ``status``, ``describe``, recordings, plots, ``watch``, the Foxglove and PlotJuggler
streams and the Bluesky signals all read it through this layout (docs/protocol.md, "The
cycle record"). A field's name says whose it is and what it is:

- ``cycle`` [-], ``t`` [s]: the clock;
- ``<joint>.position``, ``<joint>.velocity`` [rad, rad/s or m, m/s], and every further
  measured state interface of the joint (``<joint>.p_head`` [Pa], an analog input by its name);
- ``<joint>.setpoint`` and ``<joint>.error`` (set-point minus position): the reference;
- ``<joint>.u.<command>``: each command interface in force (NaN outside ``enabled``: no
  command is in force there, the safe state is written);
- ``<joint>.p_<chamber>_cmd`` [Pa]: the chamber pressures commanded (after the clamps; the
  safe state's outside ``enabled``), for actuations that command pressures;
- ``<joint>.shadow.<command>``: what a shadow-run candidate would command (NaN without one);
- rig-level measured state by its own name (``force`` [N], ``supply_pressure`` [Pa], ...);
- ``out.<channel>`` [V]: each output channel as written;
- ``mode``: the loop's state, an index into :data:`MODES` in the record, its name in messages.

A joint may not be named after a clock, rig or output field (``cycle``, ``t``, ``mode``,
``out``, or a rig-level sensor's name), nor contain a dot: :meth:`CycleLayout.of` refuses it.
"""
from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

from daemon.wire.states import State
from hal.interfaces import DISPLAY, RigInterfaces

MODES = tuple(s.value for s in State)
MODE_INDEX = {s: float(i) for i, s in enumerate(State)}
CLOCK = ("cycle", "t")
GROUPS = ("clock", "measured", "reference", "command", "commanded", "shadow", "output", "mode")


@dataclass(frozen=True)
class Field:
    """One number of the cycle record."""

    name: str  # as messages and recordings name it
    unit: str  # SI ("-" for a count or an index)
    owner: str  # the joint's name; "" for the clock, the rig's sensors, outputs and the mode
    quantity: str  # the name without its owner: "position", "u.v_mv", "p_head_cmd", "out.ao0" ...
    group: str  # one of GROUPS
    index: int  # where it sits in the record

    @property
    def display(self) -> tuple[str, float]:
        """(unit, scale) a person reads it in: deg for rad, mm for m, kPa for Pa, else the SI unit."""
        return DISPLAY.get(self.unit, (self.unit, 1.0))

    def describe(self) -> dict:
        unit, scale = self.display
        return {"name": self.name, "unit": self.unit, "owner": self.owner, "quantity": self.quantity,
                "group": self.group, "display_unit": unit, "display_scale": scale}


class CycleLayout:
    """The fields of one cycle's record, in record order, with the slices the loop writes."""

    def __init__(self, fields: list[Field]):
        self.fields = tuple(fields)
        self.names = tuple(f.name for f in self.fields)
        self.width = len(self.fields)
        self._by_name = {f.name: f for f in self.fields}
        if len(self._by_name) != self.width:
            seen: set[str] = set()
            dup = next(n for n in self.names if n in seen or seen.add(n))
            raise ValueError(f"cycle layout: field {dup!r} declared twice")
        self.row = struct.Struct(f"<{self.width}d")
        self.id = zlib.crc32("\n".join(f"{f.name} {f.unit}" for f in self.fields).encode())  # names a layout in a batch

    # -- building ---------------------------------------------------------------------------
    @classmethod
    def of(cls, rig: RigInterfaces) -> "CycleLayout":
        """The layout of a rig's declared interfaces (the order is the record's)."""
        reserved = {*CLOCK, "mode", "out", *(s.name for s in rig.rig)}
        for j in rig.joints:
            if j.name in reserved or "." in j.name or not j.name:
                raise ValueError(f"joint {j.name!r}: a joint's name may not be empty, contain a dot, or be one of "
                                 f"{', '.join(sorted(reserved))} (the cycle record's own fields)")
        out: list[Field] = []

        def add(owner: str, quantity: str, unit: str, group: str) -> None:
            out.append(Field(f"{owner}.{quantity}" if owner else quantity, unit, owner, quantity, group, len(out)))

        add("", "cycle", "-", "clock")
        add("", "t", "s", "clock")
        # group by group, each joint in turn: each group is one slice of the record the loop
        # writes with one assignment (the loop's lists are per group: angles, velocities ...)
        for k, quantity in enumerate(("position", "velocity")):
            for j in rig.joints:
                add(j.name, quantity, j.state[k].unit, "measured")
        for quantity in ("setpoint", "error"):
            for j in rig.joints:
                add(j.name, quantity, j.position_unit, "reference")
        for j in rig.joints:
            for c in j.commands:
                add(j.name, f"u.{c.name}", c.unit, "command")
        for k in range(2):  # the first chambers, then the second (the loop's pressure pair lists)
            for j in rig.joints:
                if len(j.commanded_pressures) == 2:
                    add(j.name, f"p_{j.commanded_pressures[k]}_cmd", "Pa", "commanded")
        for j in rig.joints:
            for s in j.measured():
                add(j.name, s.name, s.unit, "measured")
        for s in rig.rig:
            add("", s.name, s.unit, "measured")
        for ch in rig.outputs:
            add("", f"out.{ch}", "V", "output")
        for j in rig.joints:
            for c in j.commands:
                add(j.name, f"shadow.{c.name}", c.unit, "shadow")
        add("", "mode", "-", "mode")
        return cls(out)

    def describe(self) -> list[dict]:
        """What ``describe`` gives as ``cycle_layout``: every field, in record order."""
        return [f.describe() for f in self.fields]

    @classmethod
    def from_describe(cls, fields: list[dict]) -> "CycleLayout":
        """The layout a daemon's ``describe`` (or a recording's metadata) gives."""
        return cls([Field(f["name"], f["unit"], f["owner"], f["quantity"], f["group"], i) for i, f in enumerate(fields)])

    # -- reading ----------------------------------------------------------------------------
    def __getitem__(self, name: str) -> Field:
        return self._by_name[name]

    def __contains__(self, name: str) -> bool:
        return name in self._by_name

    def owners(self) -> list[str]:
        """The joints, in record order."""
        return list(dict.fromkeys(f.owner for f in self.fields if f.owner))

    def of_joint(self, joint: str, group: str | None = None) -> list[Field]:
        return [f for f in self.fields if f.owner == joint and (group is None or f.group == group)]

    def of_group(self, group: str) -> list[Field]:
        return [f for f in self.fields if f.group == group]

    def span(self, group: str, quantity: str | None = None, owner: str | None = None) -> tuple[int, int]:
        """(start, stop) of the record indices of ``group`` (optionally one ``quantity`` across
        joints, or the rig's own: ``owner`` ""), which must be contiguous: the slices the loop
        writes. An empty group is (0, 0)."""
        idx = [f.index for f in self.fields if f.group == group and (quantity is None or f.quantity == quantity)
               and (owner is None or f.owner == owner)]
        if not idx:
            return 0, 0
        if idx != list(range(idx[0], idx[0] + len(idx))):
            raise ValueError(f"cycle layout: {group} {quantity or ''} is not one contiguous span")
        return idx[0], idx[-1] + 1

    def record(self) -> list[float]:
        """A fresh record: NaN everywhere (a number nobody wrote is said to be missing)."""
        return [math.nan] * self.width

    # -- the state topic ----------------------------------------------------------------------
    def columns(self, rows: list[tuple[float, ...]]) -> dict[str, list]:
        """A batch of records as the ``state`` message's columns (``mode`` by name, ``cycle``
        an integer)."""
        cols = {name: [r[i] for r in rows] for i, name in enumerate(self.names)}
        cols["cycle"] = [int(c) for c in cols["cycle"]]
        cols["mode"] = [MODES[int(m)] for m in cols["mode"]]
        return cols
