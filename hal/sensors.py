"""Every sensor of a rig, placed: which joint (or the rig) it belongs to, the name it reports by
and its driver, in the one order the declared interfaces (:func:`hal.declare.declare`), the
rig's reading (:class:`hal.rig.Snapshot`), the transports' channels
(:func:`hal.transport.rig_channels`) and the simulator all follow:

- each joint's position sensor (``position``), joint by joint;
- then the *measured* sensors: each joint's chamber transmitters (``p_head``, ``p_rod``; a muscle
  pair's ``p_a``, ``p_b``) and its further inputs by their names, joint by joint; then the rig's:
  the force sensor (``force``), the supply's transmitter (``supply_pressure``), its inputs.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hal.devices import Sensor, sensor_of
from hal.interfaces import ROTARY


@dataclass(frozen=True)
class Placed:
    """One sensor where the rig file put it."""

    owner: str  # the joint's name; "" for the rig
    joint: int  # the joint's index; -1 for the rig
    name: str  # what it reports: "position", "p_head", "force", an input's name ...
    label: str  # how a fault names it: "joint bottom angle sensor", "force sensor" ...
    doc: str  # what the value is, for the declared interface
    config: Any
    sensor: Sensor


def positions(rig) -> list[Placed]:
    """Each joint's position sensor, in joint order, its plausibility against the joint's limits."""
    out = []
    for i, j in enumerate(rig.joints):
        what = "angle" if j.kind == ROTARY else "position"
        out.append(Placed(j.name, i, "position", f"joint {j.name} {what} sensor", f"the joint's {what}", j.sensor,
                          sensor_of(j.sensor, j.limits)))
    return out


def measured(rig) -> list[Placed]:
    """Every sensor read besides the positions, in the declared order (module docstring)."""
    out = []
    for i, j in enumerate(rig.joints):
        for chamber, config in j.chamber_sensors():
            out.append(Placed(j.name, i, f"p_{chamber}", f"joint {j.name} {chamber} pressure sensor",
                              f"chamber {chamber}'s pressure, measured (gauge)", config, sensor_of(config)))
        for inp in j.inputs:
            out.append(Placed(j.name, i, inp.name, f"joint {j.name} input {inp.name}", f"input {inp.name} "
                              f"({inp.sensor.device})", inp.sensor, sensor_of(inp.sensor)))
    if rig.force_sensor is not None:
        out.append(Placed("", -1, "force", "force sensor", "the tip force", rig.force_sensor,
                          sensor_of(rig.force_sensor)))
    if rig.supply_pressure is not None:
        out.append(Placed("", -1, "supply_pressure", "supply pressure sensor", "the supply's pressure, measured (gauge)",
                          rig.supply_pressure, sensor_of(rig.supply_pressure)))
    for inp in rig.inputs:
        out.append(Placed("", -1, inp.name, f"input {inp.name}", f"input {inp.name} ({inp.sensor.device})", inp.sensor,
                          sensor_of(inp.sensor)))
    return out
