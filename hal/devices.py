"""Sensor kinds are plugins: a class registered under the entry-point group ``pneumad.devices``
(pneumad's own in its pyproject.toml, a lab's in its own package's), found by the name a rig
file's table gives (``device = "rdc506"``) and imported only when a rig names it.

A kind is a subclass of :class:`Sensor` (single channel) or :class:`Ratiometric` (a signal read
against a supply, as a potentiometer is), with:

- ``Config``: a frozen dataclass its table is built from, strictly (:mod:`hal.schema`: an
  unknown key is refused by name), with the fields ``device`` (the kind's name, e.g.
  ``device: str = "pt100"``) and ``channel`` (its input channel); a ratiometric kind's also
  ``supply_channel`` ("" for none: its nominal supply) and ``supply_volts``;
- ``unit``: the SI unit of what it reads ("" when its config's ``unit`` says, as the ``analog``
  kind's does); a rig file puts it where that unit fits (a joint's position sensor reads the
  joint's unit, a chamber transmitter Pa, a force sensor N);
- ``create(config, limits)``: the driver, given the range [SI] the rig knows for the value (a
  joint's travel, for a position sensor; unbounded elsewhere); it sets ``low``, ``high``, the
  range it declares (:class:`hal.interfaces.StateInterface`);
- ``convert(volts)`` [SI, NaN when the reading cannot be true] and ``diagnose(volts)`` (why, or
  None): a ratiometric kind's take ``(volts, supply_volts)``; ``volts_for(value)`` (a
  ratiometric kind's ``ratio_for(value)``): the reading the kind expects, which the simulator
  makes (linear, as every built-in kind's is).

The loop reads each sensor once a cycle through :meth:`Sensor.read` (channels bound once, by
:meth:`Sensor.bind`); :mod:`hal.sensors` places them on the rig.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, ClassVar

from hal.errors import ConfigError
from hal.plugins import installed, load_entry_point
from hal.schema import Invalid, build

GROUP = "pneumad.devices"
# SI units a reading may be declared in (``1``: a pure number)
SI_UNITS = ("m", "rad", "m/s", "rad/s", "m/s^2", "rad/s^2", "Pa", "N", "N m", "K", "V", "A", "W", "kg", "s", "Hz",
            "kg/s", "m^3", "m^3/s", "1")
NOT_SI = {"mm": ("m", 1e-3), "cm": ("m", 1e-2), "deg": ("rad", math.pi / 180.0), "mm/s": ("m/s", 1e-3),
          "deg/s": ("rad/s", math.pi / 180.0), "bar": ("Pa", 1e5), "mbar": ("Pa", 1e2), "kPa": ("Pa", 1e3),
          "MPa": ("Pa", 1e6), "psi": ("Pa", 6894.757), "kN": ("N", 1e3), "Nm": ("N m", 1.0), "N*m": ("N m", 1.0),
          "g": ("kg", 1e-3), "ms": ("s", 1e-3), "mV": ("V", 1e-3), "mA": ("A", 1e-3), "degC": ("K", None),
          "°C": ("K", None), "C": ("K", None), "%": ("1", 0.01), "l/min": ("m^3/s", 1e-3 / 60.0)}


class Sensor:
    """One input device on one channel: volts -> a value in SI units, with plausibility."""

    Config: ClassVar[type]
    unit: ClassVar[str] = ""  # the SI unit it reads; "": its config's ``unit``

    def __init__(self, config):
        self.config = config
        self.low, self.high = -math.inf, math.inf  # the range it declares [SI]
        self._index = -1

    @classmethod
    def create(cls, config, limits: tuple[float, float] = (-math.inf, math.inf)) -> "Sensor":
        """The driver of ``config``, placed where the rig knows its value's range ``limits`` [SI]."""
        return cls(config)

    @property
    def si_unit(self) -> str:
        return self.unit or self.config.unit

    def bind(self, index: int, supply_index: int = -1) -> None:
        """Where its channel sits in the transport's input sweep (done once, before the loop)."""
        self._index = index

    def read(self, values: Sequence[float]) -> float:
        """This cycle's value [SI] from the input sweep, NaN when it cannot be true."""
        return self.convert(values[self._index])

    def fault(self, values: Sequence[float]) -> str:
        """Why :meth:`read` gave NaN, in words."""
        return self.diagnose(values[self._index]) or "implausible reading"

    def convert(self, volts: float) -> float:
        raise NotImplementedError

    def diagnose(self, volts: float) -> str | None:
        raise NotImplementedError

    def volts_for(self, value: float) -> float:
        """What the sensor reads for ``value`` [SI] (the simulator's sensor)."""
        raise NotImplementedError


class Ratiometric(Sensor):
    """A signal read as a ratio of its supply, measured on ``supply_channel`` or taken as the
    nominal ``supply_volts`` (a potentiometer: its resistance tolerance cancels)."""

    def __init__(self, config):
        super().__init__(config)
        self._supply = -1

    def bind(self, index: int, supply_index: int = -1) -> None:
        self._index, self._supply = index, supply_index

    def read(self, values: Sequence[float]) -> float:
        s = self._supply
        return self.convert(values[self._index], values[s] if s >= 0 else self.config.supply_volts)

    def fault(self, values: Sequence[float]) -> str:
        s = self._supply
        return self.diagnose(values[self._index], values[s] if s >= 0 else self.config.supply_volts) or \
            "implausible reading"

    def convert(self, volts: float, supply_volts: float) -> float:  # type: ignore[override]
        raise NotImplementedError

    def diagnose(self, volts: float, supply_volts: float) -> str | None:  # type: ignore[override]
        raise NotImplementedError

    def ratio_for(self, value: float) -> float:
        raise NotImplementedError

    def volts_for(self, value: float, supply_volts: float | None = None) -> float:
        return (self.config.supply_volts if supply_volts is None else supply_volts) * self.ratio_for(value)


def sensor_kind(name: str) -> type[Sensor]:
    """The sensor kind registered as ``name`` (or at a ``module:Class`` path); LookupError
    naming what is installed, or the plugin's own error if it fails to import."""
    return load_entry_point(name, GROUP, Sensor, "device kind")


def kinds() -> list[str]:
    """The names of every installed sensor kind (nothing is imported)."""
    return sorted(installed(GROUP))


def sensor_of(config, limits: tuple[float, float] = (-math.inf, math.inf)) -> Sensor:
    """The driver of a parsed device table."""
    return sensor_kind(config.device).create(config, limits)


def parse_sensor(table: Any, key: str, default: str, unit: str = "", slot: str = "") -> Any:
    """A sensor table's config, of the kind its ``device`` names (``default`` if it names none),
    its keys checked by that kind's ``Config``; where the place needs a ``unit`` (``slot`` says
    what the place is), the kind must read it. Raises :class:`hal.schema.Invalid` naming the key
    under ``key`` (the caller's table adds its own path). A config already built (a rig
    changed with :func:`dataclasses.replace`) is checked again as it is."""
    if dataclasses.is_dataclass(table) and not isinstance(table, type):
        config = table
        name = getattr(config, "device", default)
    else:
        if not isinstance(table, dict):
            raise Invalid(key, f"expected a table, got {type(table).__name__}")
        name = table.get("device", default)
        if not isinstance(name, str):
            raise Invalid(f"{key}.device", f"expected a string naming a device kind, got {name!r}")
        config = None
    try:
        kind = sensor_kind(name)
    except LookupError as exc:
        raise Invalid(f"{key}.device", str(exc)) from None
    if unit and kind.unit and kind.unit != unit:
        raise _wrong_unit(key, name, kind.unit, unit, slot)
    if "device" not in {f.name for f in dataclasses.fields(kind.Config)}:
        raise Invalid(f"{key}.device", f"device kind {name!r}: its Config has no `device` field (a kind's Config "
                      f"names its kind: device: str = {name!r})")
    if config is None:
        try:
            config = build(kind.Config, {**table, "device": name})
        except ConfigError as exc:
            inner, _, message = str(exc).partition(": ")
            raise Invalid(f"{key}.{inner}", message) from None
    read = kind.unit or getattr(config, "unit", "")
    if not kind.unit:
        check_si(read, f"{key}.unit")
    if unit and read != unit:
        raise _wrong_unit(key, name, read, unit, slot)
    return config


def _wrong_unit(key: str, name: str, read: str, unit: str, slot: str) -> Invalid:
    fix = suggest_for(unit)
    return Invalid(f"{key}.device", f"device kind {name!r} reads {read or 'no unit'}, but {slot} is in {unit}: "
                   f"name a kind that reads {unit}" + (f" (device = {fix!r})" if fix else ""))


def suggest_for(unit: str) -> str:
    """The built-in kind for a place that reads ``unit``, if there is one."""
    return {"rad": "rdc506", "m": "linear_potentiometer", "Pa": "pressure_transmitter", "N": "asfs"}.get(unit, "")


def check_si(unit: str, key: str) -> None:
    """Invalid unless ``unit`` is an SI unit the rig may declare a reading in, with the fix."""
    if unit in SI_UNITS:
        return
    if unit in NOT_SI:
        si, factor = NOT_SI[unit]
        fix = (f"multiply per_volt, low and high by {factor:g}" if factor is not None
               else "give per_volt in K/V and low, high in K (0 degC = 273.15 K)")
        raise Invalid(key, f"{unit!r} is not SI: state the reading in {si} ({fix})")
    raise Invalid(key, f"{unit!r} is not an SI unit a reading is declared in (one of: {', '.join(SI_UNITS)})")
