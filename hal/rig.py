"""Rig I/O: a transport plus the device drivers the rig file names, in SI units.

:meth:`RigIO.read` turns one raw input sweep into a :class:`Snapshot` (angles in rad, force
in N); :meth:`RigIO.write_pressures` turns chamber pressure commands [Pa] into regulator
volts and writes them in one sweep. The mapping is checked against the channels the
transport declares when the object is built, before anything moves.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from hal.config import RigConfig
from hal.errors import ConfigError
from hal.force_sensor import ASFS
from hal.potentiometer import RDC506
from hal.regulator import ITV0051
from hal.transport import Transport


@dataclass(slots=True)
class Snapshot:
    """One cycle's inputs in SI units; NaN marks a reading that cannot be true, with the
    reason in ``faults`` (empty when all is well)."""

    seq: int
    t: float  # sample time [s]
    angles: tuple[float, ...]  # joint angles [rad]
    force: float  # tip force [N], NaN when the rig has no force sensor or it is implausible
    faults: tuple[str, ...]
    volts: tuple[float, ...]  # the raw sweep, in the transport's input order [V]


class RigIO:
    def __init__(self, config: RigConfig, transport: Transport):
        self.config = config
        self.transport = transport
        self.joint_names = tuple(j.name for j in config.joints)
        for ch in transport.outputs:
            if ch.is_input:
                raise ConfigError(f"{transport.backend}: channel {ch.name} declared as an output but is an input")
        self._pots = [RDC506(j.sensor, *j.limits_rad) for j in config.joints]
        self._angle_idx = [transport.index(j.sensor.channel, output=False) for j in config.joints]
        self._supply_idx = [transport.index(j.sensor.supply_channel, output=False) if j.sensor.supply_channel else -1
                            for j in config.joints]
        self.head = [ITV0051(j.head) for j in config.joints]
        self.rod = [ITV0051(j.rod) for j in config.joints]
        self._head_idx = [transport.index(j.head.channel, output=True) for j in config.joints]
        self._rod_idx = [transport.index(j.rod.channel, output=True) for j in config.joints]
        self.force_sensor = ASFS(config.force_sensor) if config.force_sensor else None
        self._force_idx = transport.index(config.force_sensor.channel, output=False) if config.force_sensor else -1
        self._p_max = config.limits.max_pressure_mpa * 1e6
        # Outputs no device claims are held at 0 V.
        self.safe_pressures = (tuple(r.config.safe_mpa * 1e6 for r in self.head),
                               tuple(r.config.safe_mpa * 1e6 for r in self.rod))
        self.safe_volts = tuple(self.volts_for(*self.safe_pressures))
        self.bias_pressures = (tuple(r.bias_pa for r in self.head), tuple(r.bias_pa for r in self.rod))
        self.last_volts = self.safe_volts

    def read(self) -> Snapshot:
        """One input sweep in SI units. Raises :class:`hal.errors.TransportError` on failure."""
        sweep = self.transport.read()
        v = sweep.values
        angles = []
        faults: list[str] | tuple = ()
        for name, pot, ia, isup in zip(self.joint_names, self._pots, self._angle_idx, self._supply_idx):
            supply = v[isup] if isup >= 0 else pot.config.supply_volts
            a = pot.angle(v[ia], supply)
            if a != a:  # NaN: say why, off the common path
                faults = [*faults, f"joint {name} angle sensor: {pot.diagnose(v[ia], supply)}"]
            angles.append(a)
        force = math.nan
        if self.force_sensor is not None:
            vf = v[self._force_idx]
            reason = self.force_sensor.diagnose(vf)
            if reason is None:
                force = self.force_sensor.force(vf)
            else:
                faults = [*faults, f"force sensor: {reason}"]
        return Snapshot(sweep.seq, sweep.t, tuple(angles), force, tuple(faults), v)

    def volts_for(self, p_head: Sequence[float], p_rod: Sequence[float]) -> list[float]:
        """The output sweep for chamber pressures [Pa], each limited to the rig's maximum.
        A non-finite pressure raises :class:`hal.errors.CommandError` naming the channel."""
        out = [0.0] * len(self.transport.outputs)
        p_max = self._p_max
        for reg, ih, p in zip(self.head, self._head_idx, p_head):
            out[ih] = reg.volts(p_max if p > p_max else p)  # NaN goes on, to be refused
        for reg, ir, p in zip(self.rod, self._rod_idx, p_rod):
            out[ir] = reg.volts(p_max if p > p_max else p)
        return out

    def write_pressures(self, p_head: Sequence[float], p_rod: Sequence[float]) -> list[float]:
        """Command the chamber pressures [Pa]: all outputs are written, or none."""
        volts = self.volts_for(p_head, p_rod)
        self.transport.write(volts)
        self.last_volts = volts
        return volts

    def write_safe(self) -> None:
        """Write the configured safe state (a commanded pressure pair per joint)."""
        self.transport.write(self.safe_volts)
        self.last_volts = self.safe_volts

    def tare_force(self, volts: float | None = None) -> None:
        """Zero the force sensor on ``volts`` (default: a fresh reading)."""
        if self.force_sensor is None:
            raise ConfigError("this rig has no force sensor")
        if volts is None:
            volts = self.transport.read().values[self._force_idx]
        self.force_sensor.tare(volts)
