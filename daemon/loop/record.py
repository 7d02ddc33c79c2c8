"""Where each group of the cycle record sits: the spans of the layout
(:class:`daemon.wire.cycle_layout.CycleLayout`) that hold the loop's own lists, found once when
the loop is built and checked to tile the record in the order the cycle writes them, so a cycle
writes its record as one list display of its lists (C's gather: half the cost of a dozen slice
assignments into a list kept from cycle to cycle) and never looks a field up by name. A layout
the loop cannot fill exactly (a group of the wrong size or out of order, a command the
actuation does not have) is refused here, before anything runs."""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

from daemon.wire.cycle_layout import CycleLayout


class RecordSpans(NamedTuple):
    """The record's slices, in the loop's terms (each a ``slice`` of the record), and what a
    cycle writes where nothing is in force."""

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
    def of(cls, layout: CycleLayout, joints: list[str], commands: list[str], pressure_joints: list[int],
           sensors: list[str], outputs: list[str]) -> "RecordSpans":
        """The spans of ``layout`` for a loop of the joints ``joints`` (by name, in order), whose
        actuation commands ``commands`` (``<joint>.<name>`` each, in its vector's order) and the
        chamber pressures of the joints ``pressure_joints`` (by index), whose snapshot measures
        the fields ``sensors`` (by name, in its order) and whose transport writes the channels
        ``outputs``. Each span must hold those, in that order, and the spans must tile the
        record in the order the cycle writes them."""
        def span(group: str, names: list[str], quantity: str | None = None, name=lambda f: f.owner) -> slice:
            start, stop = layout.span(group, quantity)
            found = [name(f) for f in layout.fields[start:stop]]
            if found != list(names):
                raise ValueError(f"cycle layout: {group} {quantity or ''} holds {found}, the loop writes {list(names)}")
            return slice(start, stop)

        n = len(pressure_joints)
        owners = [joints[i] for i in pressure_joints]
        sensor_names = [f.name for f in layout.fields if f.group == "measured" and f.quantity not in ("position", "velocity")]
        if sensor_names != list(sensors):
            raise ValueError(f"cycle layout: sensors {sensor_names}, the snapshot measures {list(sensors)}")
        first = layout[sensor_names[0]].index if sensor_names else 0
        commanded = span("commanded", owners * 2)
        spans = cls(span("measured", joints, "position"), span("measured", joints, "velocity"),
                    span("reference", joints, "setpoint"), span("reference", joints, "error"),
                    span("command", commands, name=lambda f: f"{f.owner}.{f.quantity[2:]}"),
                    slice(commanded.start, commanded.start + n), slice(commanded.start + n, commanded.stop),
                    None if pressure_joints == list(range(len(joints))) else tuple(pressure_joints),
                    slice(first, first + len(sensors)), span("output", outputs, name=lambda f: f.quantity[4:]),
                    span("shadow", commands, name=lambda f: f"{f.owner}.{f.quantity[7:]}"),
                    layout["mode"].index, (math.nan,) * len(commands), (math.nan,) * len(sensors))
        order = [o for o in (slice(0, 1), slice(1, 2), *spans[:7], *spans[8:11], slice(spans.mode, spans.mode + 1))
                 if o.stop > o.start]  # (a group the rig has not is empty)
        if [(o.start, o.stop) for o in order] != list(zip([0, *(o.stop for o in order[:-1])], [o.stop for o in order])) \
                or order[-1].stop != layout.width or layout.names[:2] != ("cycle", "t"):
            raise ValueError(f"cycle layout: its groups are not in the order the loop writes them ({', '.join(layout.names)})")
        return spans


def writer(spans: RecordSpans, joints: int, modes: dict, enabled) -> Callable:
    """The loop's ``_record(snap)`` for these spans (bound to the loop): this cycle's record, one
    list display in record order from the loop's own lists, each joint's error (set-point minus
    position) and each pressure joint's pair spelled out; NaN for the commands outside
    ``enabled`` (the safe state is written, no command is in force), for the sensors when the
    cycle's read failed (``snap`` None), and for the shadow without a candidate; ``mode`` the
    state's index in ``modes``, looked up only when the state changes (an Enum's hash is a Python
    call). A new list each cycle, never changed once made: a reader may keep it.

    Made from source once, as :mod:`dataclasses` makes its methods: a ``map(operator.sub, ...)``
    over two joints, and a call passing the loop's lists to a writer, each cost as much as the
    rest of the record (docs/benchmarks.md, "The cycle record")."""
    def pick(name: str) -> list[str]:
        return [f"*{name}"] if spans.pressure_joints is None else [f"{name}[{i}]" for i in spans.pressure_joints]

    parts = ["self.cycle", "snap.t if snap is not None else self.clock.now()", "*a", "*self.velocities", "*s",
             *(f"s[{i}] - a[{i}]" for i in range(joints)), "*(self.u if state is ENABLED else NO_COMMANDS)",
             *pick("self.p_head"), *pick("self.p_rod"), "*(snap.measured if snap is not None else NO_SENSORS)",
             "*self.io.last_volts", "*(run.u if run is not None and run.u is not None else NO_COMMANDS)",
             "self._mode_index"]
    source = ("def _record(self, snap):\n"
              "    state, run, a, s = self.supervisor.state, self.shadow_run, self.angles, self.reference[0]\n"
              "    if state is not self._mode_of:\n"
              "        self._mode_of, self._mode_index = state, MODES[state]\n"
              f"    self.record = [{', '.join(parts)}]\n")
    scope = {"MODES": modes, "ENABLED": enabled, "NO_COMMANDS": spans.no_commands, "NO_SENSORS": spans.no_sensors}
    exec(compile(source, "<the cycle record's writer>", "exec"), scope)  # noqa: S102 (source made above, from indices)
    return scope["_record"]
