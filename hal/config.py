"""The rig configuration: one TOML file names the transport, the channel map, every device's
calibration, joint limits, pressure limits and the safe state (docs/rigs.md: every key).

Config files use engineering units named in each key (``_deg``, ``_mpa``, ``_mm``); the
properties here give SI values to the code. With no file the daemon runs a built-in rig
(:data:`BUILTIN_RIGS`): the simulated 2-joint arm, the 3-joint one with the top joint, the
muscle joint, or the linear axis. A joint's keys are in :mod:`hal.joints`; the small tables
(``[arm]``, ``[safety]``, ...) in :mod:`hal.rig_sections`; sensors are device kinds found by
name (:mod:`hal.devices`).
"""
from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from hal.devices import parse_sensor
from hal.errors import ConfigError
from hal.identified import IDENTIFIED, JointParams, parse_models
from hal.interfaces import LINEAR
from hal.joints import CYLINDER, JointConfig, parse_input
from hal.rig_sections import (ArmConfig, FlightRecorderConfig, LimitsConfig, ModelWatchConfig, RigInfo, SafetyConfig,
                              TimingConfig, TransportConfig)
from hal.schema import build, require
from hal.taxel_array import ContactSensorConfig

BUILTIN_RIGS = {"sim": "sim_2joint.toml", "sim-3joint": "sim_3joint.toml", "sim-muscle": "sim_muscle.toml",
                "sim-axis": "sim_axis.toml"}
RIG_INPUT_NAMES = ("cycle", "t", "mode", "out", "force", "supply_pressure")  # the record's own names


@dataclass(frozen=True)
class RigConfig:
    rig: RigInfo
    transport: TransportConfig
    joints: tuple[JointConfig, ...]
    arm: ArmConfig | None = None  # a rig of rotary joints: its planar arm (default: 2 links of 100 mm)
    limits: LimitsConfig = LimitsConfig()
    safety: SafetyConfig = SafetyConfig()
    timing: TimingConfig = TimingConfig()  # when the loop's timing is degraded, and what then
    flight_recorder: FlightRecorderConfig = FlightRecorderConfig()  # the last seconds, written on each trip
    model_watch: ModelWatchConfig = ModelWatchConfig()  # the rig's model beside the arm (docs/model.md)
    force_sensor: Any = None  # the tip force sensor's table (device default "asfs")
    supply_pressure: Any = None  # a transmitter on the supply line (device default "pressure_transmitter")
    inputs: tuple[Any, ...] = ()  # [[inputs]]: further analog inputs of the rig
    contact_sensor: ContactSensorConfig | None = None  # the array pressure sensor, beside the loop
    models: dict[str, Any] = field(default_factory=dict)  # [models.NAME] tables (hal.identified.parse_models)
    # [controllers.NAME] tables: a controller's parameters on this rig, over its own defaults (their names
    # and values are checked against the controller when the daemon builds its loop: daemon.assembly)
    controllers: dict[str, Any] = field(default_factory=dict)
    joint_models: dict[str, JointParams] = field(default_factory=dict, init=False, compare=False)  # built-in + own
    source: str = field(default="", init=False, compare=False)  # the TOML text it was built from
    origin: str = field(default="", init=False, compare=False)  # a path or "builtin:NAME"

    def __post_init__(self):
        require(len(self.joints) >= 1, "joints", "at least one joint is needed")
        try:
            object.__setattr__(self, "joint_models", {**IDENTIFIED, **parse_models(self.models, IDENTIFIED)})
        except ValueError as exc:
            key, _, message = str(exc).partition(": ")
            require(False, key, message)
        for i, j in enumerate(self.joints):
            require(not j.model or j.model in self.joint_models, f"joints[{i}].model",
                    f"no model {j.model!r} (known: {', '.join(self.joint_models)})")
        names = [j.name for j in self.joints]
        dup = _first_duplicate(names)
        require(dup is None, "joints", f"joint name {dup!r} is used twice")
        for name, table in self.controllers.items():
            require(isinstance(table, dict), f"controllers.{name}",
                    "must be a table of the controller's parameters (a number, or one per joint)")
        self._check_arm()
        self._parse_sensors()
        self._check_channels()
        for i, j in enumerate(self.joints):
            for device, (where, _) in zip(j.pressure_outputs, j.output_channels()):
                require(device.safe_mpa <= self.limits.max_pressure_mpa, f"{where}.safe_mpa",
                        f"{device.safe_mpa} MPa exceeds limits.max_pressure_mpa {self.limits.max_pressure_mpa}")
            lo, hi = j.limits
            key = "setpoint_margin_mm" if j.kind == LINEAR else "setpoint_margin_deg"
            require(2.0 * self.setpoint_margins[i] < hi - lo, f"safety.{key}",
                    f"{getattr(self.safety, key)} leaves joint {j.name} no set-point inside its limits {j.shown_limits()}")
            if j.actuation == CYLINDER:  # V_MV's range must hold 0 (the bias) inside the pressure limit
                for where, device in (("head", j.head), ("rod", j.rod)):
                    bias_mpa = device.offset_mpa + device.mpa_per_volt * device.bias_volts  # [2-29]
                    require(bias_mpa < self.limits.max_pressure_mpa, f"joints[{i}].{where}.bias_volts",
                            f"{device.bias_volts} V is {bias_mpa:.3f} MPa, not below limits.max_pressure_mpa "
                            f"{self.limits.max_pressure_mpa}: lower the bias or raise the limit")

    def _check_arm(self) -> None:
        linear = [j.name for j in self.joints if j.kind == LINEAR]
        if linear:
            require(self.arm is None or not self.arm.link_lengths_mm, "arm",
                    f"a rig with a linear joint ({', '.join(linear)}) is not a planar arm of rotary joints: "
                    f"leave [arm] out")
            object.__setattr__(self, "arm", ArmConfig(link_lengths_mm=()))
            return
        if self.arm is None:
            object.__setattr__(self, "arm", ArmConfig())
        require(len(self.arm.link_lengths_mm) == len(self.joints), "arm.link_lengths_mm",
                f"{len(self.arm.link_lengths_mm)} links given for {len(self.joints)} joints")

    def _parse_sensors(self) -> None:
        if self.force_sensor is not None:
            object.__setattr__(self, "force_sensor", parse_sensor(self.force_sensor, "force_sensor", "asfs", "N",
                                                                  "the tip force"))
        if self.supply_pressure is not None:
            object.__setattr__(self, "supply_pressure", parse_sensor(
                self.supply_pressure, "supply_pressure", "pressure_transmitter", "Pa", "the supply's pressure"))
        inputs = tuple(parse_input(t, f"inputs[{k}]", RIG_INPUT_NAMES) for k, t in enumerate(self.inputs))
        object.__setattr__(self, "inputs", inputs)
        names = [i.name for i in inputs]
        dup = _first_duplicate(names)
        require(dup is None, "inputs", f"input name {dup!r} is used twice")
        clash = set(names) & {j.name for j in self.joints}
        require(not clash, "inputs", f"input {sorted(clash)!r} has a joint's name: name it apart")

    def input_devices(self) -> list[tuple[str, Any]]:
        """(where, config) of every input device the rig file names, in the sweep's order
        (:func:`hal.transport.rig_channels`): the joints' position sensors, each joint's chamber
        transmitters and inputs, then the rig's force sensor, supply transmitter and inputs."""
        out = [(f"joints.{j.name}.sensor", j.sensor) for j in self.joints]
        for j in self.joints:
            out += [(f"joints.{j.name}.pressure_{c}", s) for c, s in j.chamber_sensors()]
            out += [(f"joints.{j.name}.inputs.{i.name}", i.sensor) for i in j.inputs]
        if self.force_sensor is not None:
            out.append(("force_sensor", self.force_sensor))
        if self.supply_pressure is not None:
            out.append(("supply_pressure", self.supply_pressure))
        out += [(f"inputs.{i.name}", i.sensor) for i in self.inputs]
        return out

    def supply_channels(self) -> list[str]:
        """The distinct supply channels ratiometric sensors read, in order of first use."""
        return list(dict.fromkeys(ch for _, c in self.input_devices() if (ch := getattr(c, "supply_channel", ""))))

    def _check_channels(self) -> None:
        outputs = [o for j in self.joints for o in j.output_channels()]
        signals = [(where, config.channel) for where, config in self.input_devices()]
        for group in (outputs, signals):
            seen: dict[str, str] = {}
            for where, channel in group:
                require(channel not in seen, where + ".channel",
                        f"channel {channel!r} is already mapped to {seen.get(channel)}")
                seen[channel] = where
        clash = set(self.supply_channels()) & {c for _, c in signals}
        require(not clash, "joints", f"channel {sorted(clash)} is both a supply and a signal channel")

    @property
    def setpoint_margins(self) -> tuple[float, ...]:
        """How far inside its limits each joint's set-points must be [rad; m on a linear joint]:
        ``[safety] setpoint_margin_deg`` (``setpoint_margin_mm``)."""
        return tuple(self.safety.setpoint_margin_mm * 1e-3 if j.kind == LINEAR
                     else math.radians(self.safety.setpoint_margin_deg) for j in self.joints)

    def joint_params(self, joint: JointConfig) -> JointParams | None:
        """The model a joint names (``model``, else its own name), or None when there is none."""
        return self.joint_models.get(joint.model_name)

    @property
    def hash(self) -> str:
        """SHA-256 of the source text: what a recording names to say which rig it came from."""
        return hashlib.sha256(self.source.encode()).hexdigest()


def _first_duplicate(items):
    seen = set()
    for item in items:
        if item in seen:
            return item
        seen.add(item)
    return None


def parse(text: str, origin: str = "<string>") -> RigConfig:
    """Build and validate a rig configuration from TOML text."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{origin}: not valid TOML: {exc}") from None
    try:
        config = build(RigConfig, data)
    except ConfigError as exc:
        raise ConfigError(f"{origin}: {exc}") from None
    if not origin.startswith("builtin:"):
        _require_stated(data, origin)
    object.__setattr__(config, "source", text)
    object.__setattr__(config, "origin", origin)
    return config


STATED = {"transport": "backend", "safety": None, "arm": None, "limits": None}  # what a rig file must say itself
# ([arm]: a rig of rotary joints only)
STATED_TYPES = {"transport": TransportConfig, "safety": SafetyConfig, "arm": ArmConfig, "limits": LimitsConfig}


def _require_stated(data: dict, origin: str) -> None:
    """A rig file states its transport backend, its safety limits, its arm and its pressure
    limits: defaults for them are the built-in rigs' alone, so a mistyped real rig's file never
    quietly runs the simulator, another arm's geometry or the simulator's pressure limits."""
    linear = any(isinstance(j, dict) and j.get("kind") == LINEAR for j in data.get("joints") or ())
    for section, key in STATED.items():
        if section == "arm" and linear:
            continue
        if not isinstance(data.get(section), dict):
            keys = ", ".join(f.name for f in fields(STATED_TYPES[section]) if f.init)
            raise ConfigError(f"{origin}: [{section}]: missing: a rig file must state it (only the built-in rigs "
                              f"have defaults; copy [{section}] from hal/sim_2joint.toml and set its {keys} "
                              f"for this rig)")
        if key is not None and key not in data[section]:
            raise ConfigError(f"{origin}: {section}.{key}: missing: a rig file must name its transport backend "
                              f"(\"sim\" for the simulator, or serial, modbus, can)")


def load(path: str | Path | None = None) -> RigConfig:
    """Load a rig file, a built-in rig by name (:data:`BUILTIN_RIGS`), or the default (``sim``)."""
    if path is None or str(path) in BUILTIN_RIGS:
        name = "sim" if path is None else str(path)
        text = resources.files("hal").joinpath(BUILTIN_RIGS[name]).read_text()
        return parse(text, f"builtin:{name}")
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read rig file: {exc.strerror}") from None
    return parse(text, str(p))


def with_transport(rig: RigConfig, backend: str, options: dict[str, Any]) -> RigConfig:
    """The same rig (joints, channels, limits) reached through another transport: what
    ``pneumad --transport`` does. The source text records the override, so the rig's hash
    (which recordings carry) tells the two apart."""
    changed = replace(rig, transport=TransportConfig(backend, dict(options)))
    note = f"\n# overridden on the command line: [transport] backend = {backend!r}, options = {options!r}\n"
    object.__setattr__(changed, "source", rig.source + note)
    object.__setattr__(changed, "origin", rig.origin)
    return changed


def with_safety(rig: RigConfig, changes: dict[str, Any]) -> RigConfig:
    """The rig with some ``[safety]`` values replaced, checked as the file's own are (``pneumad
    --safety KEY=VALUE``: e.g. a PC without real-time scheduling, which cannot keep a 5 ms stale
    limit across a wire). The source text records the override, so the rig's hash tells them
    apart."""
    current = {f.name: getattr(rig.safety, f.name) for f in fields(SafetyConfig) if f.init}
    safety = build(SafetyConfig, {**current, **changes}, "safety")
    changed = replace(rig, safety=safety)
    note = "\n# overridden on the command line: [safety] " + ", ".join(f"{k} = {v!r}" for k, v in changes.items()) + "\n"
    object.__setattr__(changed, "source", rig.source + note)
    object.__setattr__(changed, "origin", rig.origin)
    return changed


def parse_option(text: str, what: str = "transport option") -> tuple[str, Any]:
    """``KEY=VALUE`` with VALUE read as a TOML value (a number, true, a quoted string, an
    array), or else as a plain string: ``port=/dev/ttyACM0``, ``baudrate=921600``."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"{what} {text!r}: expected KEY=VALUE")
    try:
        return key.strip(), tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        return key.strip(), value
