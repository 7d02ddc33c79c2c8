"""Rig I/O: a transport plus the device drivers the rig file names, in SI units.

:meth:`RigIO.read` turns one raw input sweep into a :class:`Snapshot`: each joint's position
(rad or m), and every further sensor's reading (chamber pressures in Pa, force in N, further
inputs in their units) in the order the rig declares them (:mod:`hal.sensors`).
:meth:`RigIO.write_pressures` turns each joint's pressure pair [Pa] (a cylinder's head and rod
chambers through its regulators, a muscle pair's through its valves) and the direct commands (a
brake's torque [N m], a 5/3 valve's volts about its centre [V]) into volts, one sweep. The
mapping is checked against the channels the transport declares when the object is built, before
anything moves.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from hal import sensors
from hal.config import RigConfig
from hal.directional_valve import DirectionalValve
from hal.errors import ConfigError
from hal.joints import MUSCLE_PAIR, VALVE
from hal.mr_brake import MRBrake
from hal.regulator import ITV0051
from hal.transport import Transport
from hal.valve import ProportionalValve, ValveConfig


@dataclass(slots=True)
class Snapshot:
    """One cycle's inputs in SI units; NaN marks a reading that cannot be true, with the
    reason in ``faults`` (empty when all is well)."""

    seq: int
    t: float  # sample time [s]
    angles: tuple[float, ...]  # each joint's position [rad on a rotary joint, m on a linear one]
    force: float  # tip force [N], NaN when the rig has no force sensor or it is implausible
    faults: tuple[str, ...]
    volts: tuple[float, ...]  # the raw sweep, in the transport's input order [V]
    pressures: tuple[float, ...] = ()  # measured (first, second) chamber per joint, flattened [Pa]; NaN: none or implausible
    measured: tuple[float, ...] = ()  # every sensor besides the positions, in declare()'s order [SI]; NaN: implausible


@dataclass(frozen=True)
class PressureDrivers:
    """Each joint's two pressure-output drivers (a cylinder's head and rod ITV0051 regulators,
    a muscle pair's proportional valves; None for a joint on a 5/3 valve), built once per rig and
    shared by the rig's I/O (pressures -> volts) and its command interfaces (V_MV -> pressures)."""

    head: tuple  # per joint, the first chamber's driver
    rod: tuple  # per joint, the second chamber's driver

    @classmethod
    def of(cls, config: RigConfig) -> "PressureDrivers":
        pairs = [j.pressure_outputs or (None, None) for j in config.joints]
        return cls(tuple(_pressure_device(p[0]) for p in pairs), tuple(_pressure_device(p[1]) for p in pairs))


def direct_outputs(config: RigConfig) -> list[tuple[str, object]]:
    """The outputs written as they are commanded, in joint order: each muscle pair's brake
    (torque [N m]), each 5/3 valve (volts about its centre [V]); as (channel, driver)."""
    out: list[tuple[str, object]] = []
    for j in config.joints:
        if j.actuation == VALVE:
            out.append((j.valve.channel, DirectionalValve(j.valve)))
        elif j.actuation == MUSCLE_PAIR and j.brake is not None:
            out.append((j.brake.channel, MRBrake(j.brake)))
    return out


class RigIO:
    def __init__(self, config: RigConfig, transport: Transport, drivers: PressureDrivers | None = None):
        """``drivers``: the rig's pressure drivers when they are shared (:mod:`daemon.assembly`);
        default: built here."""
        self.config = config
        self.transport = transport
        self.joint_names = tuple(j.name for j in config.joints)
        self.position_units = tuple(j.position_unit for j in config.joints)  # "rad" or "m" per joint
        for ch in transport.outputs:
            if ch.is_input:
                raise ConfigError(f"{transport.backend}: channel {ch.name} declared as an output but is an input")
        self._positions = [self._bound(p) for p in sensors.positions(config)]
        placed = sensors.measured(config)
        self._measured = [self._bound(p) for p in placed]
        # each joint's chamber pair, as the controllers take them: slot 2 i + chamber, from the measured
        self._pressure_slots = [(2 * p.joint + (0 if p.name in ("p_head", "p_a") else 1), k)
                                for k, p in enumerate(placed) if p.name.startswith("p_") and p.owner]
        self._no_pressures = (math.nan,) * (2 * len(config.joints))
        self._force_k = next((k for k, p in enumerate(placed) if not p.owner and p.name == "force"), -1)
        self.force_sensor = placed[self._force_k].sensor if self._force_k >= 0 else None
        # each joint's pressure pair: a cylinder's head and rod regulators, a muscle pair's valves
        drivers = drivers or PressureDrivers.of(config)
        self.head, self.rod = list(drivers.head), list(drivers.rod)
        self._pairs = [(i, head, transport.index(head.config.channel, output=True), rod,
                        transport.index(rod.config.channel, output=True))
                       for i, (head, rod) in enumerate(zip(self.head, self.rod)) if head is not None]
        self._direct = [(driver, transport.index(channel, output=True)) for channel, driver in direct_outputs(config)]
        # each joint's output channels (head, rod[, brake]; a valve), by name: what status says was written
        self.joint_outputs = [tuple(ch for _, ch in j.output_channels()) for j in config.joints]
        self._p_max = config.limits.max_pressure_mpa * 1e6
        # Outputs no device claims are held at 0 V.
        self.safe_pressures = (tuple(r.config.safe_mpa * 1e6 if r is not None else 0.0 for r in self.head),
                               tuple(r.config.safe_mpa * 1e6 if r is not None else 0.0 for r in self.rod))
        self.safe_direct = tuple(d.config.safe_nm if isinstance(d, MRBrake) else d.safe_volts - d.centre
                                 for d, _ in self._direct)
        self.safe_volts = tuple(self.volts_for(*self.safe_pressures, self.safe_direct))
        self.bias_pressures = (tuple(getattr(r, "bias_pa", 0.0) for r in self.head),
                               tuple(getattr(r, "bias_pa", 0.0) for r in self.rod))
        self.last_volts = self.safe_volts

    def _bound(self, placed: sensors.Placed) -> tuple[str, object]:
        """(label, sensor) with the sensor bound to its channels in the sweep."""
        supply = getattr(placed.config, "supply_channel", "")
        placed.sensor.bind(self.transport.index(placed.config.channel, output=False),
                           self.transport.index(supply, output=False) if supply else -1)
        return placed.label, placed.sensor

    def read(self) -> Snapshot:
        """One input sweep in SI units. Raises :class:`hal.errors.TransportError` on failure."""
        sweep = self.transport.read()
        v = sweep.values
        faults: list[str] | tuple = ()
        angles = []
        for label, sensor in self._positions:
            a = sensor.read(v)
            if a != a:  # NaN: say why, off the common path
                faults = [*faults, f"{label}: {sensor.fault(v)}"]
            angles.append(a)
        measured = []
        for label, sensor in self._measured:
            x = sensor.read(v)
            if x != x:
                faults = [*faults, f"{label}: {sensor.fault(v)}"]
            measured.append(x)
        pressures = self._no_pressures
        if self._pressure_slots:
            pressures = list(pressures)
            for slot, k in self._pressure_slots:
                pressures[slot] = measured[k]
            pressures = tuple(pressures)
        force = measured[self._force_k] if self._force_k >= 0 else math.nan
        return Snapshot(sweep.seq, sweep.t, tuple(angles), force, tuple(faults), v, pressures, tuple(measured))

    def volts_for(self, p_head: Sequence[float], p_rod: Sequence[float], direct: Sequence[float] = ()) -> list[float]:
        """The output sweep for each joint's pressure pair [Pa] (each limited to the rig's
        maximum; a joint without pressure outputs: its entries unused) and the direct commands
        (:func:`direct_outputs`: brake torques [N m], valve volts about the centre [V]; none given:
        0 each). A non-finite command raises :class:`hal.errors.CommandError` naming the channel."""
        out = [0.0] * len(self.transport.outputs)
        p_max = self._p_max
        for i, head, ih, rod, ir in self._pairs:
            p = p_head[i]
            out[ih] = head.volts(p_max if p > p_max else p)  # NaN goes on, to be refused
            p = p_rod[i]
            out[ir] = rod.volts(p_max if p > p_max else p)
        for (driver, index), x in zip(self._direct, direct or (0.0,) * len(self._direct)):
            out[index] = driver.volts(x)
        return out

    def write_pressures(self, p_head: Sequence[float], p_rod: Sequence[float], direct: Sequence[float] = ()) -> list[float]:
        """Command the pressure pairs [Pa] and the direct commands: all outputs are written, or none."""
        volts = self.volts_for(p_head, p_rod, direct)
        self.transport.write(volts)
        self.last_volts = volts
        return volts

    def write_safe(self) -> None:
        """Write the configured safe state (a commanded pressure pair per joint, a valve's safe volts)."""
        self.transport.write(self.safe_volts)
        self.last_volts = self.safe_volts

    def tare_force(self, volts: float | None = None) -> None:
        """Zero the force sensor on ``volts`` (default: a fresh reading)."""
        if self.force_sensor is None:
            raise ConfigError("this rig has no force sensor")
        if volts is None:
            volts = self.transport.read().values[self.transport.index(self.force_sensor.config.channel, output=False)]
        self.force_sensor.tare(volts)


def _pressure_device(config):
    """The driver of one pressure output: an ITV0051 regulator or a proportional valve."""
    if config is None:
        return None
    return ProportionalValve(config) if isinstance(config, ValveConfig) else ITV0051(config)
