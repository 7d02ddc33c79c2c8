"""A read-only view of the loop, what status, describe and the replies read: built on the loop's
handles (:class:`daemon.loop.handles.LoopHandles`), never on its attributes. ``status``'s numbers
come from the latest cycle record through its layout (:mod:`daemon.wire.cycle_layout`), read when
asked; a field a rig declares reaches ``status`` with no code for it.
"""
from __future__ import annotations

import math

from daemon.loop.handles import LoopHandles
from daemon.service import realtime

TRACKED = ("position", "setpoint", "error", "velocity")  # in the joint's display unit (deg, mm; per s)


class LoopView:
    def __init__(self, handles: LoopHandles):
        self._h = handles
        self._joints = self._joint_fields()
        layout = handles.layout
        self._rig_sensors = [(f.name, f.index) for f in layout.of_group("measured") if not f.owner]

    # -- what the loop runs on (fixed once it is built) -----------------------------------
    @property
    def rig(self):
        return self._h.rig

    @property
    def context(self):
        """The controllers' build context (controllers.base)."""
        return self._h.context

    @property
    def controller_plugins(self) -> dict[str, str]:
        return self._h.controller_plugins

    @property
    def period(self) -> float:
        return self._h.period

    @property
    def layout(self):
        """The cycle record's layout (daemon.wire.cycle_layout)."""
        return self._h.layout

    @property
    def command_interfaces(self):
        return self._h.command_interfaces

    @property
    def transport(self):
        return self._h.transport

    # -- its state now --------------------------------------------------------------------
    def now(self) -> float:
        return self._h.clock.now()

    @property
    def cycle(self) -> int:
        return self._h.cycle()

    @property
    def state(self):
        return self._h.supervisor.state

    @property
    def enabled(self) -> bool:
        return self._h.supervisor.enabled

    @property
    def controller(self):
        """The active controller (read its name and parameters; change it through the controls)."""
        return self._h.controller()

    @property
    def shadowing(self) -> bool:
        return self._h.shadow() is not None

    @property
    def shadow_controller(self):
        """The shadow run's candidate, None without one."""
        run = self._h.shadow()
        return None if run is None else run.controller

    @property
    def controller_dirs(self):
        """The controller directories' files (controllers.directory.Directories)."""
        return self._h.controller_dirs

    def measured_state(self):
        """The measured state now, copied (a plugin checked beside the loop steps once on it)."""
        return self._h.measured()

    def output(self) -> list[float]:
        """The controller's share of the output in force (what a controller reset now continues from)."""
        return self._h.output()

    def reference_origin(self) -> tuple[int, list[float]]:
        """What a plan starts from: the reference generation and the set-point in force [rad]."""
        return self._h.origin()

    def reference_running(self) -> tuple[str, float]:
        """The reference's name and how long it runs on [s] (0 once ended, or for a hold)."""
        return self._h.reference()

    def recovery(self) -> dict | None:
        """Joints enabled outside their limits on their way back, as enabled
        (:meth:`daemon.loop.recovery.Recovery.describe`), or None."""
        recovery = self._h.supervisor.recovery
        return None if recovery is None else recovery.summary

    def load(self) -> dict | None:
        """The known load fed forward and its feed-forward per joint [V], or None."""
        ff = self._h.feed_forward
        if ff.load is None:
            return None
        return {**ff.load.describe(), "feedforward_volts": dict(zip(self._h.layout.owners(), ff.volts))}

    def status(self) -> dict:
        """The loop's fields of ``status`` (the lease's, the client's and the daemon's are the
        handler's); ``cycle``, ``t``, ``joints`` and ``rig`` are the latest cycle record's."""
        h = self._h
        record = h.record()  # one cycle's numbers (a later cycle makes a new list)
        sup, shadow = h.supervisor, h.shadow()
        name, remaining = h.reference()
        enabled = sup.enabled
        return {
            "state": sup.state.value,
            "cause": sup.cause,
            "cycle": int(record[0]),
            "t": record[1],
            "controller": h.controller().name,
            "shadow": shadow.summary() if shadow is not None else None,
            "reference": name if enabled else None,
            "reference_remaining_s": remaining if enabled else 0.0,
            "joints": {joint: self._joint(record, *fields, enabled) for joint, *fields in self._joints},
            "rig": {name: _number(record[k]) for name, k in self._rig_sensors},
            "faults": list(h.faults()),
            "trips": sup.trips,
            "overruns_total": h.stats.overruns_total,
            "scheduling": realtime.describe(),  # the loop thread's, as the system granted it
            "load": self.load(),
            "transport": vars(h.transport.health()),
            "telemetry": None,  # the port's, where one serves the loop (daemon.loop.port)
            "helpers": None,
            "model": None,  # the port's too: the model beside the arm (daemon.model.process)
        }

    def _joint_fields(self) -> list[tuple]:
        """Per joint, once: (name, its display unit and scale, where each of its fields sits in
        the record, grouped as ``status`` gives them, whether it takes a stiffness set-point)."""
        layout, out = self._h.layout, []
        for i, joint in enumerate(layout.owners()):
            unit, scale = layout[f"{joint}.position"].display
            fields = layout.of_joint(joint)
            tracked = [(f.quantity, f.index) for f in fields if f.quantity in TRACKED]
            commands = [(f.quantity[2:], f.index) for f in fields if f.group == "command"]
            commanded = [(f.quantity, f.index) for f in fields if f.group == "commanded"]
            measured = [(f.quantity, f.index) for f in fields if f.group == "measured" and f.quantity not in TRACKED]
            written = [(ch, layout[f"out.{ch}"].index) for ch in self._h.joint_outputs[i]]
            stiff = self._h.rig.joints[i].muscles is not None
            out.append((joint, i, unit, scale, tracked, commands, commanded, measured, written, stiff))
        return out

    def _joint(self, r: list, i: int, unit: str, scale: float, tracked, commands, commanded, measured, written,
               stiff: bool, enabled: bool) -> dict:
        """One joint in ``status``: position, set-point, error and velocity in the unit a person
        reads the joint in (``unit``: deg on a rotary joint, mm on a linear one; velocity per
        second); ``output``: ``controller``, or ``safe state`` outside ``enabled``, where the safe
        state is written and no command is in force (each command null); its commands, commanded
        chamber pressures and measured values [SI] by name; ``written_volts``: its output channels
        as last written [V]; a muscle pair's stiffness set-point [N m/deg] (null: the controller's)."""
        out = {"unit": unit, **{q: r[k] * scale for q, k in tracked},
               "output": "controller" if enabled else "safe state",
               "commands": {c: _number(r[k]) for c, k in commands},
               "commanded": {q: _number(r[k]) for q, k in commanded},
               "measured": {q: _number(r[k]) for q, k in measured},
               "written_volts": {ch: r[k] for ch, k in written}}
        if stiff:
            k = self._h.stiffness()[i]
            out["stiffness_nm_deg"] = None if k != k else math.radians(k)
        return out


def _number(x: float) -> float | None:
    """A record's number as ``status`` gives it: null for NaN (nothing written, or implausible)."""
    return None if x != x else x
