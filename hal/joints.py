"""One joint of a rig file (``[[joints]]``): its kind and limits, its position sensor, its
actuation and the further sensors wired to it. docs/rigs.md describes every key.

- **Kind.** ``rotary`` (the default; SI rad, limits in ``min_angle_deg``, ``max_angle_deg``,
  ``max_speed_deg_s``) or ``linear`` (SI m; ``min_position_mm``, ``max_position_mm``,
  ``max_speed_mm_s``). One kind's keys on the other are refused by name, with the fix.
- **Position sensor** ``[joints.sensor]``: a device kind reading the joint's unit, ``rdc506``
  on a rotary joint and ``linear_potentiometer`` on a linear one unless ``device`` says otherwise.
- **Actuation**, what the devices it names make it: a regulator pair (``head``, ``rod``: SMC
  ITV0051s; actuation ``cylinder``), an antagonistic muscle pair (``muscles``, ``valve_a``,
  ``valve_b``, ``pressure_a``, ``pressure_b``, ``link``, optionally ``brake``; ``muscle_pair``),
  or a 5/3 proportional directional valve (``valve``; ``valve``), which a linear joint takes,
  with ``linear_axis`` (:class:`hal.linear_axis.AxisParams`: its cylinder, load and valve, which
  the simulator and model-based controllers use).
- **Sensors** beside: a cylinder's chamber transmitters ``pressure_head``, ``pressure_rod`` (a
  muscle pair's are ``pressure_a``, ``pressure_b``), and further analog inputs ``[[joints.inputs]]``
  (``name`` and a device's keys; the default ``analog`` kind: ``channel``, ``unit``, ``per_volt``,
  ``offset``, ``low``, ``high``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from hal.devices import parse_sensor
from hal.directional_valve import DirectionalValve, DirectionalValveConfig
from hal.interfaces import DISPLAY, LINEAR, POSITION_UNIT, ROTARY
from hal.linear_axis import AxisParams
from hal.mr_brake import BrakeConfig, MRBrake
from hal.muscle import MuscleConfig
from hal.regulator import LinearPressureCommand, RegulatorConfig
from hal.schema import Invalid, require
from hal.valve import ValveConfig

CYLINDER, MUSCLE_PAIR, VALVE = "cylinder", "muscle_pair", "valve"  # the actuations a joint can declare
DEFAULT_SENSOR = {ROTARY: "rdc506", LINEAR: "linear_potentiometer"}
LIMIT_KEYS = {ROTARY: ("min_angle_deg", "max_angle_deg", "max_speed_deg_s"),
              LINEAR: ("min_position_mm", "max_position_mm", "max_speed_mm_s")}
ONLY = {ROTARY: ("neutral_angle_deg", "model"), LINEAR: ("linear_axis",)}  # keys of one kind alone, beside its limits
DEFAULT_SPEED = {ROTARY: 60.0, LINEAR: 500.0}  # [deg/s], [mm/s]
ACTUATION_KEYS = {CYLINDER: ("head", "rod"), MUSCLE_PAIR: ("muscles", "valve_a", "valve_b", "link", "brake"),
                  VALVE: ("valve",)}  # the devices that make a joint's actuation (its sensors aside)
REQUIRED = {CYLINDER: ("head", "rod"), MUSCLE_PAIR: ("muscles", "valve_a", "valve_b", "pressure_a", "pressure_b", "link"),
            VALVE: ("valve",)}
ACTUATION_WORDS = {CYLINDER: "a cylinder (head, rod)", MUSCLE_PAIR: "a muscle pair (muscles, valve_a, ...)",
                   VALVE: "a 5/3 valve (valve)"}
CHAMBER_SENSORS = {CYLINDER: ("pressure_head", "pressure_rod"), MUSCLE_PAIR: ("pressure_a", "pressure_b"),
                   VALVE: ("pressure_head", "pressure_rod")}
CHAMBERS = {CYLINDER: ("head", "rod"), MUSCLE_PAIR: ("a", "b"), VALVE: ("head", "rod")}
INPUT_NAMES_TAKEN = ("position", "velocity", "setpoint", "error", "stiffness", "u", "shadow")


@dataclass(frozen=True)
class LinkConfig:
    """The link a joint carries, for its gravity and inertia (rig-facts §2 gives the muscle
    joint's: 0.168 kg, centre of gravity 240 mm, 4.80e-3 kg m^2 about the joint)."""

    mass_kg: float
    com_mm: float
    inertia_kg_m2: float

    def __post_init__(self):
        require(0 < self.mass_kg <= 100, "mass_kg", "must be within (0, 100] kg")
        require(0 <= self.com_mm <= 5000, "com_mm", "must be within 0-5000 mm")
        require(0 < self.inertia_kg_m2 <= 100, "inertia_kg_m2", "must be within (0, 100] kg m^2")


@dataclass(frozen=True)
class NamedInput:
    """A further analog input: the name it is reported by and its device's config."""

    name: str
    sensor: Any


@dataclass(frozen=True)
class JointConfig:
    """One joint (module docstring). Sensor tables are parsed here, by the device kind they
    name; ``kind``'s limits are required, the other kind's refused."""

    name: str
    sensor: Any  # the position sensor's table (hal.devices), its config once parsed
    kind: str = ROTARY
    min_angle_deg: float | None = None  # software limits the supervisor enforces [deg]
    max_angle_deg: float | None = None
    max_speed_deg_s: float | None = None  # faster than this is a trip [deg/s]; default 60
    model: str = ""  # the joint's model: a [models.NAME] table or a built-in set (hal/models.toml); default: name
    neutral_angle_deg: float | None = None  # th_0 of the joint's spring; default: mid-range [deg]
    min_position_mm: float | None = None  # a linear joint's software limits [mm]
    max_position_mm: float | None = None
    max_speed_mm_s: float | None = None  # default 500
    head: RegulatorConfig | None = None  # head-side chamber, commanded V_INI + V_MV [2-30]
    rod: RegulatorConfig | None = None  # rod-side chamber, held at V_INI [2-31]
    valve: DirectionalValveConfig | None = None  # a 5/3 proportional directional valve
    linear_axis: AxisParams | None = None  # a valve-driven linear joint's cylinder, load and valve
    pressure_head: Any = None  # chamber transmitters on a cylinder (regulators or a 5/3 valve)
    pressure_rod: Any = None
    muscles: MuscleConfig | None = None  # muscle a pulls the angle up, muscle b down
    valve_a: ValveConfig | None = None
    valve_b: ValveConfig | None = None
    pressure_a: Any = None
    pressure_b: Any = None
    link: LinkConfig | None = None
    brake: BrakeConfig | None = None
    inputs: tuple[Any, ...] = ()  # [[joints.inputs]]: further analog inputs

    def __post_init__(self):
        require(bool(self.name), "name", "must not be empty")
        require(self.kind in (ROTARY, LINEAR), "kind", f'must be "{ROTARY}" or "{LINEAR}", got {self.kind!r}')
        self._check_limits()
        actuation = self._check_actuation()
        object.__setattr__(self, "sensor", parse_sensor(self.sensor, "sensor", DEFAULT_SENSOR[self.kind],
                                                        self.position_unit,
                                                        f"joint {self.name!r}'s position ({self.kind})"))
        for key in CHAMBER_SENSORS[actuation]:
            if getattr(self, key) is not None:
                object.__setattr__(self, key, parse_sensor(getattr(self, key), key, "pressure_transmitter", "Pa",
                                                           "a chamber's pressure"))
        object.__setattr__(self, "inputs", tuple(parse_input(t, f"inputs[{k}]", INPUT_NAMES_TAKEN + tuple(
            f"p_{c}" for c in self.chambers)) for k, t in enumerate(self.inputs)))
        names = [i.name for i in self.inputs]
        dup = next((n for k, n in enumerate(names) if n in names[:k]), None)
        require(dup is None, "inputs", f"input name {dup!r} is used twice")

    def _check_limits(self) -> None:
        other = LINEAR if self.kind == ROTARY else ROTARY
        for key in LIMIT_KEYS[other] + ONLY[other]:
            value = getattr(self, key)
            if value is not None and value != "":
                fix = (f'set kind = "{other}" for a {other} joint' if self.kind == ROTARY
                       else "a linear joint's limits are " + ", ".join(LIMIT_KEYS[LINEAR]))
                raise Invalid(key, f"a {self.kind} joint has no {key} ({fix}; "
                                   f"a {self.kind} joint's keys are {', '.join(LIMIT_KEYS[self.kind] + ONLY[self.kind])})")
        low_key, high_key, speed_key = LIMIT_KEYS[self.kind]
        for key in (low_key, high_key):
            require(getattr(self, key) is not None, key,
                    f"missing required key (a {self.kind} joint's limits: {low_key}, {high_key})")
        low, high = getattr(self, low_key), getattr(self, high_key)
        require(low < high, high_key, f"limits inverted: min {low} >= max {high}")
        if getattr(self, speed_key) is None:
            object.__setattr__(self, speed_key, DEFAULT_SPEED[self.kind])
        require(getattr(self, speed_key) > 0, speed_key, "must be > 0")

    def _check_actuation(self) -> str:
        present = {a: [k for k in keys if getattr(self, k) is not None] for a, keys in ACTUATION_KEYS.items()}
        named = [a for a, keys in present.items() if keys]
        if len(named) > 1:
            keys = present[named[1]]
            raise Invalid(keys[0], f"a joint is {' or '.join(ACTUATION_WORDS[a] for a in named)}, not both "
                                   f"({', '.join(present[named[0]])} and {', '.join(keys)} given)")
        if not named:
            raise Invalid("head", "missing: a joint names its actuation: head and rod (a regulator pair), muscles, "
                                  "valve_a, valve_b ... (a muscle pair), or valve (a 5/3 proportional valve)")
        actuation = named[0]
        for other, keys in CHAMBER_SENSORS.items():
            for key in keys:
                if getattr(self, key) is not None and key not in CHAMBER_SENSORS[actuation]:
                    raise Invalid(key, f"{ACTUATION_WORDS[actuation]}'s chamber transmitters are "
                                       f"{' and '.join(CHAMBER_SENSORS[actuation])} ({key} is {ACTUATION_WORDS[other]}'s)")
        missing = [k for k in REQUIRED[actuation] if getattr(self, k) is None]
        words = {CYLINDER: "cylinder", MUSCLE_PAIR: "muscle-pair", VALVE: "valve"}[actuation]
        require(not missing, missing[0] if missing else "",
                f"missing: a {words} joint names {', '.join(REQUIRED[actuation])}")
        if self.kind == LINEAR:
            require(actuation == VALVE, named and present[actuation][0],
                    "a linear joint is driven by a 5/3 proportional valve ([joints.valve]); regulator pairs and "
                    "muscle pairs drive rotary joints")
            stroke_mm = (self.linear_axis or AxisParams()).stroke_m * 1e3
            require(0.0 <= self.min_position_mm and self.max_position_mm <= stroke_mm, "max_position_mm",
                    f"the limits {self.min_position_mm:g}..{self.max_position_mm:g} mm must lie within the cylinder's "
                    f"stroke, 0..{stroke_mm:g} mm (position from the retracted end; linear_axis.stroke_m)")
        return actuation

    # -- what the rest of the code reads --------------------------------------------------
    @property
    def actuation(self) -> str:
        if self.muscles is not None:
            return MUSCLE_PAIR
        return VALVE if self.valve is not None else CYLINDER

    @property
    def position_unit(self) -> str:
        return POSITION_UNIT[self.kind]

    @property
    def limits(self) -> tuple[float, float]:
        """The software limits [SI: rad or m]."""
        if self.kind == LINEAR:
            return self.min_position_mm * 1e-3, self.max_position_mm * 1e-3
        return math.radians(self.min_angle_deg), math.radians(self.max_angle_deg)

    @property
    def max_speed(self) -> float:
        """Faster than this is a trip [SI: rad/s or m/s]."""
        return self.max_speed_mm_s * 1e-3 if self.kind == LINEAR else math.radians(self.max_speed_deg_s)

    def shown(self, value: float, per_second: bool = False) -> str:
        """A position [SI] (or a speed, ``per_second``) as a person reads it: "12.3 deg", "45.0 mm/s"."""
        unit, scale = DISPLAY[self.position_unit + ("/s" if per_second else "")]
        return f"{value * scale:.1f} {unit}"

    def shown_limits(self) -> str:
        """The limits as a person reads them: "85.0..175.0 deg", "10.0..190.0 mm"."""
        low, high = self.limits
        unit, scale = DISPLAY[self.position_unit]
        return f"{low * scale:.1f}..{high * scale:.1f} {unit}"

    @property
    def limits_rad(self) -> tuple[float, float]:
        """A rotary joint's limits [rad] (the planar arm's)."""
        return math.radians(self.min_angle_deg), math.radians(self.max_angle_deg)

    @property
    def pressure_outputs(self) -> tuple:
        """The two pressure-commanding devices' configs: (head, rod) or (valve_a, valve_b); none
        for a 5/3 valve, which commands flow."""
        if self.actuation == VALVE:
            return ()
        return (self.head, self.rod) if self.muscles is None else (self.valve_a, self.valve_b)

    @property
    def chambers(self) -> tuple[str, str]:
        return CHAMBERS[self.actuation]

    def chamber_sensors(self) -> list[tuple[str, Any]]:
        """(chamber, transmitter config) of each chamber with a transmitter wired."""
        return [(chamber, getattr(self, key)) for chamber, key in zip(self.chambers, CHAMBER_SENSORS[self.actuation])
                if getattr(self, key) is not None]

    def output_channels(self) -> list[tuple[str, str]]:
        """(where, channel) of every output the joint drives, in sweep order."""
        keys = {CYLINDER: ("head", "rod"), MUSCLE_PAIR: ("valve_a", "valve_b", "brake"), VALVE: ("valve",)}
        return [(f"joints.{self.name}.{k}", getattr(self, k).channel) for k in keys[self.actuation]
                if getattr(self, k) is not None]

    def safe_volts(self) -> list[float]:
        """What each of the joint's outputs is held at in its safe state [V], in the order of
        :meth:`output_channels`: a pressure device's ``safe_mpa``, a brake's ``safe_nm``, a
        valve's ``safe_volts``."""
        if self.actuation == VALVE:
            return [DirectionalValve(self.valve).safe_volts]
        out = [LinearPressureCommand(device).safe_volts for device in self.pressure_outputs]
        if self.brake is not None:
            out.append(MRBrake(self.brake).volts(self.brake.safe_nm))
        return out

    @property
    def model_name(self) -> str:
        return self.model or self.name

    @property
    def neutral_deg(self) -> float:
        if self.neutral_angle_deg is not None:
            return self.neutral_angle_deg
        return 0.5 * (self.min_angle_deg + self.max_angle_deg)


def parse_input(table: Any, key: str, taken: tuple[str, ...] = ()) -> NamedInput:
    """One ``[[inputs]]`` or ``[[joints.inputs]]`` table: its ``name`` and its device (default
    ``analog``); Invalid naming the key under ``key``."""
    if isinstance(table, NamedInput):
        return NamedInput(table.name, parse_sensor(table.sensor, key, "analog"))
    if not isinstance(table, dict):
        raise Invalid(key, f"expected a table, got {type(table).__name__}")
    name = table.get("name")
    require(isinstance(name, str) and name.isidentifier(), f"{key}.name",
            f"an input needs a name, letters, digits and _ (it names the reading: e.g. name = \"supply_temp\"); "
            f"got {name!r}")
    require(name not in taken, f"{key}.name", f"{name!r} is a name the rig reports already (taken: {', '.join(taken)})")
    return NamedInput(name, parse_sensor({k: v for k, v in table.items() if k != "name"}, key, "analog"))
