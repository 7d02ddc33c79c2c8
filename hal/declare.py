"""A configured rig's interfaces (:mod:`hal.interfaces`) from its rig file: what each joint and
the rig report and are commanded with. Everything downstream (the cycle record, telemetry,
recordings, status) follows what this returns; the measured state comes in the order of
:mod:`hal.sensors`, which :class:`hal.rig.Snapshot`'s ``measured`` follows too."""
from __future__ import annotations

from collections.abc import Sequence

from hal import sensors
from hal.actuation import RigActuation
from hal.config import RigConfig
from hal.interfaces import DISPLAY, JointInterfaces, RigInterfaces, StateInterface
from hal.joints import VALVE


def declare(rig: RigConfig, outputs: Sequence[str], actuation: RigActuation | None = None) -> RigInterfaces:
    """The interfaces of ``rig``, whose transport writes ``outputs`` (channel names, in sweep order)."""
    actuation = actuation or RigActuation(rig)
    measured = sensors.measured(rig)
    joints = []
    for i, (j, pos) in enumerate(zip(rig.joints, sensors.positions(rig))):
        low, high = j.limits
        unit = j.position_unit
        state = [StateInterface(j.name, "position", unit, low, high, pos.doc),
                 StateInterface(j.name, "velocity", f"{unit}/s", -j.max_speed, j.max_speed,
                                "filtered difference of the position")]
        state += [_interface(p) for p in measured if p.joint == i]
        commands = tuple(c for c in actuation.commands if c.joint == j.name)
        commanded = () if j.actuation == VALVE else j.chambers
        joints.append(JointInterfaces(j.name, j.kind, j.actuation, j.chambers, tuple(state), commands, commanded))
    rig_state = tuple(_interface(p) for p in measured if p.joint < 0)
    return RigInterfaces(tuple(joints), rig_state, tuple(outputs))


def _interface(placed: sensors.Placed) -> StateInterface:
    s = placed.sensor
    return StateInterface(placed.owner, placed.name, s.si_unit, s.low, s.high, placed.doc)


def summary(interfaces: RigInterfaces) -> list[str]:
    """What a rig declares, a line per joint and one for the rig, in the units a person reads
    (``pneumad --check`` prints it)."""
    lines = []
    for j in interfaces.joints:
        pos = j.state[0]
        unit, scale = DISPLAY.get(pos.unit, (pos.unit, 1.0))
        reads = ", ".join(f"{s.name} [{s.unit}]" for s in j.measured()) or "no further sensor"
        commands = ", ".join(f"{c.name} [{c.unit}] {c.low:g}..{c.high:g}" for c in j.commands)
        lines.append(f"joint {j.name}: {j.kind}, {pos.low * scale:g}..{pos.high * scale:g} {unit}, "
                     f"{j.actuation} ({commands}); measures {reads}")
    if interfaces.rig:
        lines.append("rig: measures " + ", ".join(f"{s.name} [{s.unit}]" for s in interfaces.rig))
    return lines
