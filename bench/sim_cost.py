"""Simulator and driver costs per 1 ms cycle (issue: HAL, device drivers and the simulated rig).

Usage: python -m bench.sim_cost
Figures: the 2-joint plant step with friction and dead time (goal <= 20 us, i.e. >= 50x
real time), in Python and compiled (sim_backend/compiled_plant.py: one call a step, and a
thousand steps in one call, as a catch-up takes them); a whole transport read (plant advance + sensor volts + noise + ADC); the
drivers' conversion of one input sweep and one output sweep, all channels.
"""
from __future__ import annotations

from bench.common import header, per_call_us
from daemon import assembly
from daemon.loop.clock import VirtualClock
from hal import config
from hal.rig import RigIO
from hal.schema import build
from hal.transport import Transport
from sim_backend.compiled_plant import CompiledArm
from sim_backend.options import SimOptions

N = 20000


def main() -> None:
    header("simulator and driver cost per cycle")
    rig = config.load()
    clock = VirtualClock()
    io = assembly.open_rig(rig, clock.now)
    transport = io.transport
    arm = transport.arm
    volts = list(io.volts_for(*io.bias_pressures))
    volts[0] = 6.0  # keep the bottom joint moving, so friction is in its slipping branch too

    plant = per_call_us(lambda: arm.step(volts), N)
    compiled_arm = CompiledArm(rig, build(SimOptions, {**rig.transport.options, "compiled": True}, "options"))
    compiled_arm.step(volts)  # compiled (or loaded from numba's cache) before it is timed
    compiled = per_call_us(lambda: compiled_arm.step(volts), N)
    batched = per_call_us(lambda: compiled_arm.advance(volts, 1000), N // 100) / 1000.0

    def sim_read():
        clock.t += 0.001
        transport.read()

    read = per_call_us(sim_read, N)
    replay = RigIO(rig, _Replay(transport))
    convert_in = per_call_us(replay.read, N)
    p_head, p_rod = io.bias_pressures
    convert_out = per_call_us(lambda: io.volts_for(p_head, p_rod), N)
    print(f"plant step, 2 joints, friction + dead time : {plant:7.2f} us   ({1000.0 / plant:5.0f}x real time at 1 ms)")
    print(f"plant step compiled, one call a step       : {compiled:7.2f} us")
    print(f"plant step compiled, 1000 steps a call     : {batched:7.2f} us")
    print(f"sim transport read (plant + sensors + ADC)  : {read:7.2f} us")
    print(f"drivers, input sweep -> SI ({len(transport.inputs)} channels)      : {convert_in:7.2f} us")
    print(f"drivers, SI -> output sweep ({len(transport.outputs)} channels)     : {convert_out:7.2f} us")


class _Replay(Transport):
    """Returns one recorded sweep at no cost, so RigIO.read's time is the drivers' alone."""

    def __init__(self, source: Transport):
        super().__init__()
        self.inputs, self.outputs = source.inputs, source.outputs
        self._sweep = source.read()

    def read(self):
        return self._sweep

    def _write(self, values):
        pass


if __name__ == "__main__":
    main()
