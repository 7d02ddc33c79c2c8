"""The simulated rig alone on a virtual clock, and a lockstep closed loop for a controller on
it (no daemon): read -> control -> write, as the loop's cycle does."""
from __future__ import annotations

from dataclasses import dataclass

from controllers.base import Controller, ControllerContext, JointState, Reference
from daemon import assembly
from daemon.loop.clock import VirtualClock
from hal import config
from hal.actuation import RigActuation
from hal.rig import PressureDrivers, RigIO

DT = 0.001  # [s]


@dataclass
class SimRig:
    clock: VirtualClock
    rig: config.RigConfig
    io: RigIO
    actuation: RigActuation

    @property
    def transport(self):
        return self.io.transport

    @property
    def arm(self):
        return self.io.transport.arm

    def context(self) -> ControllerContext:
        return ControllerContext.for_rig(self.rig, self.actuation, DT)


def make_rig(options: str = "", name: str = "sim", replace: dict[str, str] | None = None,
             text: str | None = None) -> SimRig:
    """The built-in rig (or the rig file ``text``) with extra ``[transport.options]`` lines
    (TOML) and text replacements."""
    text = config.load(name).source if text is None else text
    for old, new in (replace or {}).items():
        if old not in text:
            raise ValueError(f"make_rig: {old!r} is not in the {name} rig's text")
        text = text.replace(old, new)
    if options:  # appended to the end of [transport.options], which the [arm] table follows
        text = text.replace("\n[arm]\n", "\n" + options + "\n\n[arm]\n", 1)
    return sim_of(config.parse(text))


def sim_of(rig: config.RigConfig) -> SimRig:
    """The simulated rig of a parsed rig configuration, on its own virtual clock."""
    clock = VirtualClock()
    drivers = PressureDrivers.of(rig)
    return SimRig(clock, rig, assembly.open_rig(rig, clock.now, drivers), RigActuation(rig, drivers))


def closed_loop(sim: SimRig, controller: Controller, reference, seconds: float):
    """Run read -> control -> write in lockstep; ``reference(t)`` gives joint angles [rad].
    Returns (times, measured angles, outputs) per cycle."""
    snap = sim.io.read()
    controller.reset(JointState(snap.t, snap.angles, [0.0] * len(snap.angles)), [0.0] * len(snap.angles))
    times, angles, outputs = [], [], []
    zeros = [0.0] * len(snap.angles)
    for _ in range(int(round(seconds / DT))):
        u = controller.step(JointState(snap.t, snap.angles, zeros), Reference(reference(snap.t), zeros, zeros))
        sim.io.write_pressures(*sim.actuation.outputs(u))
        sim.clock.sleep_until(sim.clock.now() + DT)
        snap = sim.io.read()
        times.append(snap.t)
        angles.append(snap.angles)
        outputs.append(u)
    return times, angles, outputs
