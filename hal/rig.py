"""Rig I/O: a transport plus the device drivers the rig file names, in SI units.

:meth:`RigIO.read` turns one raw input sweep into a :class:`Snapshot` (angles in rad, chamber
pressures in Pa where a joint has sensors, force in N); :meth:`RigIO.write_pressures` turns
each joint's pressure pair [Pa] (a cylinder's head and rod chambers through its regulators, a
muscle pair's through its valves) and any brake torques [N m] into volts, one sweep. The mapping is checked against the channels the
transport declares when the object is built, before anything moves.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from hal.config import RigConfig
from hal.errors import ConfigError
from hal.force_sensor import ASFS
from hal.mr_brake import MRBrake
from hal.potentiometer import RDC506
from hal.pressure_sensor import PressureSensor
from hal.regulator import ITV0051
from hal.transport import Transport
from hal.valve import ProportionalValve, ValveConfig


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
    pressures: tuple[float, ...] = ()  # measured (a, b) per joint with sensors, flattened [Pa]; NaN: none or implausible


@dataclass(frozen=True)
class PressureDrivers:
    """Each joint's two pressure-output drivers (a cylinder's head and rod ITV0051 regulators,
    a muscle pair's proportional valves), built once per rig and shared by the rig's I/O
    (pressures -> volts) and its command interfaces (V_MV -> pressures)."""

    head: tuple  # per joint, the first chamber's driver
    rod: tuple  # per joint, the second chamber's driver

    @classmethod
    def of(cls, config: RigConfig) -> "PressureDrivers":
        return cls(tuple(_pressure_device(j.pressure_outputs[0]) for j in config.joints),
                   tuple(_pressure_device(j.pressure_outputs[1]) for j in config.joints))


class RigIO:
    def __init__(self, config: RigConfig, transport: Transport, drivers: PressureDrivers | None = None):
        """``drivers``: the rig's pressure drivers when they are shared (:mod:`daemon.assembly`);
        default: built here."""
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
        # each joint's pressure pair: a cylinder's head and rod regulators, a muscle pair's valves
        drivers = drivers or PressureDrivers.of(config)
        self.head, self.rod = list(drivers.head), list(drivers.rod)
        self._head_idx = [transport.index(j.pressure_outputs[0].channel, output=True) for j in config.joints]
        self._rod_idx = [transport.index(j.pressure_outputs[1].channel, output=True) for j in config.joints]
        self.brakes = [(MRBrake(j.brake), transport.index(j.brake.channel, output=True))
                       for j in config.joints if j.brake is not None]
        # each joint's output channels (head, rod[, brake]), by name: what status says was written
        self.joint_outputs = [tuple(ch for ch in (j.pressure_outputs[0].channel, j.pressure_outputs[1].channel,
                                                  j.brake.channel if j.brake is not None else None) if ch)
                              for j in config.joints]
        self._sensed = [(2 * i + side, PressureSensor(sensor), transport.index(sensor.channel, output=False),
                         f"{j.name} {'ab'[side]}") for i, j in enumerate(config.joints)
                        for side, sensor in enumerate((j.pressure_a, j.pressure_b)) if sensor is not None]
        self._no_pressures = (math.nan,) * (2 * len(config.joints))
        self.force_sensor = ASFS(config.force_sensor) if config.force_sensor else None
        self._force_idx = transport.index(config.force_sensor.channel, output=False) if config.force_sensor else -1
        self._p_max = config.limits.max_pressure_mpa * 1e6
        # Outputs no device claims are held at 0 V.
        self.safe_pressures = (tuple(r.config.safe_mpa * 1e6 for r in self.head),
                               tuple(r.config.safe_mpa * 1e6 for r in self.rod))
        self.safe_brakes = tuple(b.config.safe_nm for b, _ in self.brakes)
        self.safe_volts = tuple(self.volts_for(*self.safe_pressures, self.safe_brakes))
        self.bias_pressures = (tuple(getattr(r, "bias_pa", 0.0) for r in self.head),
                               tuple(getattr(r, "bias_pa", 0.0) for r in self.rod))
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
        pressures = self._no_pressures
        if self._sensed:
            pressures = list(pressures)
            for slot, sensor, idx, where in self._sensed:
                p = sensor.pressure(v[idx])
                if p != p:
                    faults = [*faults, f"joint {where} pressure sensor: {sensor.diagnose(v[idx])}"]
                pressures[slot] = p
            pressures = tuple(pressures)
        return Snapshot(sweep.seq, sweep.t, tuple(angles), force, tuple(faults), v, pressures)

    def volts_for(self, p_head: Sequence[float], p_rod: Sequence[float], brakes: Sequence[float] = ()) -> list[float]:
        """The output sweep for each joint's pressure pair [Pa], each limited to the rig's
        maximum, and the brakes' torques [N m] (in joint order; none: 0 N m). A non-finite
        command raises :class:`hal.errors.CommandError` naming the channel."""
        out = [0.0] * len(self.transport.outputs)
        p_max = self._p_max
        for reg, ih, p in zip(self.head, self._head_idx, p_head):
            out[ih] = reg.volts(p_max if p > p_max else p)  # NaN goes on, to be refused
        for reg, ir, p in zip(self.rod, self._rod_idx, p_rod):
            out[ir] = reg.volts(p_max if p > p_max else p)
        for (brake, ib), t in zip(self.brakes, brakes):
            out[ib] = brake.volts(t)
        return out

    def write_pressures(self, p_head: Sequence[float], p_rod: Sequence[float], brakes: Sequence[float] = ()) -> list[float]:
        """Command the pressure pairs [Pa] (and brake torques [N m]): all outputs are written, or none."""
        volts = self.volts_for(p_head, p_rod, brakes)
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


def _pressure_device(config):
    """The driver of one pressure output: an ITV0051 regulator or a proportional valve."""
    return ProportionalValve(config) if isinstance(config, ValveConfig) else ITV0051(config)
