"""A configured rig's interfaces (:mod:`hal.interfaces`) from its rig file: what each joint and
the rig report and are commanded with. Everything downstream (the cycle record, telemetry,
recordings, status) follows what this returns."""
from __future__ import annotations

import math
from collections.abc import Sequence

from hal.actuation import RigActuation
from hal.config import RigConfig
from hal.interfaces import ROTARY, JointInterfaces, RigInterfaces, StateInterface


def declare(rig: RigConfig, outputs: Sequence[str], actuation: RigActuation | None = None) -> RigInterfaces:
    """The interfaces of ``rig``, whose transport writes ``outputs`` (channel names, in sweep order)."""
    actuation = actuation or RigActuation(rig)
    joints = []
    for j in rig.joints:
        low, high = j.limits_rad
        speed = math.radians(j.max_speed_deg_s)
        state = [StateInterface(j.name, "position", "rad", low, high, "the joint's angle"),
                 StateInterface(j.name, "velocity", "rad/s", -speed, speed, "filtered difference of the angle")]
        chambers = ("head", "rod") if j.muscles is None else ("a", "b")
        for chamber, sensor in zip(chambers, (j.pressure_a, j.pressure_b)):
            if sensor is not None:
                state.append(StateInterface(j.name, f"p_{chamber}", "Pa", 0.0, sensor.range_mpa * 1e6,
                                            f"chamber {chamber}'s pressure, measured (gauge)"))
        commands = tuple(c for c in actuation.commands if c.joint == j.name)
        joints.append(JointInterfaces(j.name, ROTARY, j.actuation, chambers, tuple(state), commands, chambers))
    rig_state = []
    if rig.force_sensor is not None:
        rig_state.append(StateInterface("", "force", "N", 0.0, rig.force_sensor.range_n, "the tip force sensor"))
    return RigInterfaces(tuple(joints), tuple(rig_state), tuple(outputs))
