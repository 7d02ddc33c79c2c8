"""The rig configuration: one TOML file names the transport, the channel map, every device's
calibration, joint limits, pressure limits and the safe state (docs/rigs.md: every key).

Config files use engineering units named in each key (``_deg``, ``_mpa``, ``_mm``); the
properties here give SI values to the code. With no file the daemon runs a built-in rig
(:data:`BUILTIN_RIGS`): the simulated 2-joint arm, the 3-joint one with the top joint, the
muscle joint, or the linear axis. A joint's keys are in :mod:`hal.joints`; sensors are device
kinds found by name (:mod:`hal.devices`).
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
from hal.joints import JointConfig, parse_input
from hal.schema import build, require
from hal.taxel_array import ContactSensorConfig

BUILTIN_RIGS = {"sim": "sim_2joint.toml", "sim-3joint": "sim_3joint.toml", "sim-muscle": "sim_muscle.toml",
                "sim-axis": "sim_axis.toml"}
RIG_INPUT_NAMES = ("cycle", "t", "mode", "out", "force", "supply_pressure")  # the record's own names


@dataclass(frozen=True)
class ArmConfig:
    """Planar arm geometry (rig-facts §1; link lengths are an interpretation, default 100 mm):
    one link per joint of a rig of rotary joints; a rig with a linear joint has none."""

    link_lengths_mm: tuple[float, ...] = (100.0, 100.0)
    elbow: int = -1  # IK branch: sign of the second joint angle
    # gravity in the arm's plane (x, y) [m/s^2]: what a payload's weight pulls along
    # (**interpretation**: the source does not say how the arm stands; a vertical plane, y up)
    gravity_m_s2: tuple[float, ...] = (0.0, -9.81)

    def __post_init__(self):
        require(all(l > 0 for l in self.link_lengths_mm), "link_lengths_mm", "every link must be > 0 mm")
        require(self.elbow in (1, -1), "elbow", f"must be +1 or -1, got {self.elbow}")
        require(len(self.gravity_m_s2) == 2 and math.hypot(*self.gravity_m_s2) <= 20.0, "gravity_m_s2",
                f"two numbers (x, y) in the arm's plane, at most 20 m/s^2 long; got {list(self.gravity_m_s2)}")

    @property
    def link_lengths_m(self) -> tuple[float, ...]:
        return tuple(l * 1e-3 for l in self.link_lengths_mm)


@dataclass(frozen=True)
class LimitsConfig:
    """Rig-wide pressure limits, tighter than or equal to the regulators' own range."""

    max_pressure_mpa: float = 0.9
    max_pressure_rate_mpa_s: float = 50.0  # slew limit on each chamber command [MPa/s]
    # of the V_MV range a reference may need along its path (the rest is left to feedback):
    # at 0.8 the built-in controllers spend under 2 % of an accepted path at an output limit
    # on the nominal plant, at 1.0 up to 23 % (docs/controllers.md, "Robustness")
    authority_fraction: float = 0.8

    def __post_init__(self):
        require(0 < self.max_pressure_mpa <= 0.9, "max_pressure_mpa",
                f"must be within (0, 0.9] MPa (the ITV0051 range), got {self.max_pressure_mpa}")
        require(self.max_pressure_rate_mpa_s > 0, "max_pressure_rate_mpa_s", "must be > 0")
        require(0 < self.authority_fraction <= 1, "authority_fraction", "must be within (0, 1]")


@dataclass(frozen=True)
class SafetyConfig:
    """When the supervisor trips to the safe state."""

    bad_samples_to_trip: int = 3  # implausible samples in a row before a sensor fault trips
    stale_after_s: float = 0.005  # input older than this is stale [s]
    stall_after_s: float = 0.05  # a cycle woken this late trips [s]
    velocity_filter_hz: float = 10.0  # low-pass on the differenced angle [Hz]
    lease_ttl_s: float = 2.0  # default lease life without a renewal [s]
    # An arm left enabled with no client holding the lease (one that enabled and let go):
    # "disable" it once it has held position that long, or "hold" it until a client comes.
    unleased_action: str = "disable"
    unleased_grace_s: float = 60.0  # [s] of holding with no lease holder before the action
    # A controller that has lost a joint: its tracking error outside this band [deg; mm on a
    # linear joint] for the window [s] without closing in. "trip" to the safe state, or
    # "fallback": the configured fallback controller takes over and holds the arm where it is.
    # 0 turns the rule off.
    tracking_error_deg: float = 10.0
    tracking_error_mm: float = 10.0
    tracking_window_s: float = 2.0
    tracking_action: str = "trip"
    fallback_controller: str = "pid"

    def __post_init__(self):
        require(1 <= self.bad_samples_to_trip <= 1000, "bad_samples_to_trip", "must be within 1-1000")
        require(0 < self.stale_after_s <= 1.0, "stale_after_s", "must be within (0, 1] s")
        require(0 < self.stall_after_s <= 10.0, "stall_after_s", "must be within (0, 10] s")
        require(0 < self.velocity_filter_hz <= 500, "velocity_filter_hz", "must be within (0, 500] Hz")
        require(0.1 <= self.lease_ttl_s <= 60, "lease_ttl_s", "must be within 0.1-60 s")
        require(self.unleased_action in ("disable", "hold"), "unleased_action", 'must be "disable" or "hold"')
        require(1.0 <= self.unleased_grace_s <= 3600, "unleased_grace_s", "must be within 1-3600 s")
        require(0 <= self.tracking_error_deg <= 180, "tracking_error_deg", "must be within 0-180 deg (0: off)")
        require(0 <= self.tracking_error_mm <= 5000, "tracking_error_mm", "must be within 0-5000 mm (0: off)")
        require(0.01 <= self.tracking_window_s <= 60, "tracking_window_s", "must be within 0.01-60 s")
        require(self.tracking_action in ("trip", "fallback"), "tracking_action", 'must be "trip" or "fallback"')
        require(isinstance(self.fallback_controller, str) and bool(self.fallback_controller), "fallback_controller",
                "must name a registered controller")


@dataclass(frozen=True)
class TimingConfig:
    """When the loop's timing is degraded, and what then (the messenger judges it beside the
    loop from its stats windows: docs/faults.md, "the loop is degraded"). Over the last
    ``window_s``: the achieved rate below ``min_rate_fraction`` of 1/period, or more than
    ``max_overrun_fraction`` of the deadlines missed (overruns), or the control stage's median
    time in the last stats window (the controller's step, chiefly) above
    ``step_budget_fraction`` of the period. ``policy``: ``"warn"`` (an event, a log line and
    the status field), ``"hold"`` (also: a running reference is stopped and the arm held, motion
    commands refused while it lasts) or ``"trip"`` (also: an enabled arm trips)."""

    window_s: float = 5.0  # the sliding window judged [s]
    min_rate_fraction: float = 0.9  # of the loop's rate (1/period)
    max_overrun_fraction: float = 0.02  # of the deadlines in the window
    step_budget_fraction: float = 0.5  # of the period, for the control stage's median time
    policy: str = "warn"

    def __post_init__(self):
        require(1.0 <= self.window_s <= 600.0, "window_s", "must be within 1-600 s")
        require(0.0 <= self.min_rate_fraction <= 1.0, "min_rate_fraction", "must be within 0-1 (0: not judged)")
        require(0.0 <= self.max_overrun_fraction <= 1.0, "max_overrun_fraction", "must be within 0-1 (1: not judged)")
        require(0.0 < self.step_budget_fraction <= 100.0, "step_budget_fraction",
                "must be above 0, at most 100 (periods)")
        require(self.policy in ("warn", "hold", "trip"), "policy", 'must be "warn", "hold" or "trip"')


@dataclass(frozen=True)
class FlightRecorderConfig:
    """The flight recorder beside the loop (the recorder process; docs/recordings.md, "The flight
    recorder"): the last ``seconds`` of every telemetry topic held in memory as published, and
    written to an MCAP file on each trip, e-stop and stalled loop, from ``seconds`` before the
    event to ``after_s`` after it. Only a daemon that records (``--record-dir``) has one."""

    seconds: float = 30.0  # [s] of telemetry before the event each file holds
    after_s: float = 3.0  # [s] after it: what the safe state did

    def __post_init__(self):
        require(1.0 <= self.seconds <= 600.0, "seconds", "must be within 1-600 s")
        require(0.0 <= self.after_s <= 60.0, "after_s", "must be within 0-60 s")


@dataclass(frozen=True)
class ModelWatchConfig:
    """The rig's model beside the arm (docs/model.md): each cylinder joint's identified model
    is run on the commands the loop wrote, and the residual (measured minus predicted position)
    judged. Its RMS over the last ``window_s`` above ``band_deg`` for ``hold_s`` is drift: a
    ``model`` event naming the joint and the likely cause. ``band_deg`` is the rig's own: what
    its model's error is on the arm (the simulator's is its noise, about 0.05 deg)."""

    enabled: bool = True  # run the model beside the loop (a process of its own)
    band_deg: float = 1.0  # the residual's RMS over window_s beyond this is drift [deg]
    window_s: float = 2.0  # the residual's statistics are over this window [s]
    hold_s: float = 0.5  # outside the band this long before the event [s]
    recover_s: float = 10.0  # back inside the band this long after a drift before the event saying so [s]
    history_s: float = 30.0  # commands and residuals kept to name a cause from [s]
    publish_hz: float = 10.0  # the ``model`` topic's rate [Hz]

    def __post_init__(self):
        require(self.band_deg > 0, "band_deg", "must be > 0")
        require(0.1 <= self.window_s <= 60.0, "window_s", "must be within 0.1-60 s")
        require(0.0 <= self.hold_s <= 60.0, "hold_s", "must be within 0-60 s")
        require(0.0 <= self.recover_s <= 3600.0, "recover_s", "must be within 0-3600 s")
        require(self.window_s <= self.history_s <= 600.0, "history_s", "must be within window_s-600 s")
        require(0.1 <= self.publish_hz <= 100.0, "publish_hz", "must be within 0.1-100 Hz")


@dataclass(frozen=True)
class TransportConfig:
    """Which backend moves the raw values; ``options`` are validated by that backend."""

    backend: str = "sim"
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RigInfo:
    name: str
    description: str = ""
    controller: str = ""  # the controller the daemon starts with unless told otherwise (default: pid)
    controller_dirs: tuple[str, ...] = ()  # directories of controller plugin files, relative to the rig file

    def __post_init__(self):
        require(all(isinstance(d, str) and d for d in self.controller_dirs), "controller_dirs",
                "must be a list of directory paths (relative to the rig file)")


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
        for j in self.joints:
            for device, (where, _) in zip(j.pressure_outputs, j.output_channels()):
                require(device.safe_mpa <= self.limits.max_pressure_mpa, f"{where}.safe_mpa",
                        f"{device.safe_mpa} MPa exceeds limits.max_pressure_mpa {self.limits.max_pressure_mpa}")

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
