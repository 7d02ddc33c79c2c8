"""Options of the simulated rig: the ``[transport.options]`` table when ``backend = "sim"``."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from hal.errors import ConfigError
from hal.schema import require
from sim_backend.muscle_plant import MusclePlantOptions

FRICTION_MODELS = ("stribeck", "karnopp")
BESIDE_LOOP = ("realtime", "always", "never")


@dataclass(frozen=True)
class SimJointOptions:
    """Plant choices for one joint (``[transport.options.joints.NAME]``)."""

    model: str = ""  # the true plant's model set (a [models.NAME] of the rig, or a built-in); default: the joint's
    neutral_angle_deg: float | None = None  # th_0 of the spring; default: the rig's joint neutral angle
    initial_angle_deg: float | None = None  # default: equilibrium at the bias pressures
    end_stop_margin_deg: float = 10.0  # mechanical stops this far beyond the software limits
    # the plant's parameters where they differ from the rig file's: a rotary joint's model
    # (e.g. {T_dly = 0.04}), a linear joint's [joints.linear_axis] (e.g. {load_mass_kg = 3.0})
    overrides: dict[str, float] = field(default_factory=dict)
    initial_position_mm: float | None = None  # a linear joint's; default: mid-way between its limits
    # Drift of a cylinder joint from its model, from ``fault_at_s`` of the plant's clock on
    # (docs/simulator.md "Drift"): a chamber that leaks, friction that grew, a potentiometer
    # that reads off, a regulator that gives less than it is asked.
    fault_at_s: float = 0.0  # [s] of the plant's clock (its steps) when the drift below starts
    leak: str = ""  # "head" or "rod": that chamber leaks ...
    leak_fraction: float = 0.1  # ... and holds this fraction less than its set pressure [-]
    friction_scale: float = 1.0  # Fs and Fc of [2-45] times this [-]
    sensor_offset_deg: float = 0.0  # the potentiometer reads this much above the angle [deg] ...
    offset_ramp_s: float = 1.0  # ... reached over this long (a step reads as a jump the speed limit trips on) [s]
    sensor_offset_mm: float = 0.0  # a linear joint's potentiometer reads this much beyond its position [mm] (same ramp)
    regulator_gain: float = 1.0  # both regulators' output pressure times this [-]

    def __post_init__(self):
        require(self.end_stop_margin_deg >= 0, "end_stop_margin_deg", "must be >= 0")
        require(self.fault_at_s >= 0, "fault_at_s", "must be >= 0")
        require(self.leak in ("", "head", "rod"), "leak",
                f'must be "head" or "rod" (or "" for none), got {self.leak!r}')
        require(0 < self.leak_fraction < 1, "leak_fraction", "must be within (0, 1)")
        require(0 < self.friction_scale <= 100, "friction_scale", "must be within (0, 100]")
        require(abs(self.sensor_offset_deg) <= 90, "sensor_offset_deg", "must be within +-90 deg")
        require(self.offset_ramp_s >= 0, "offset_ramp_s", "must be >= 0")
        require(abs(self.sensor_offset_mm) <= 100, "sensor_offset_mm", "must be within +-100 mm")
        require(0 < self.regulator_gain <= 2, "regulator_gain", "must be within (0, 2]")

    def check_kind(self, joint: str, linear: bool) -> None:
        """ConfigError naming the first key set here that a joint of this kind has no use for: a
        rotary joint's (its model, angles, chambers, regulators) on a linear axis, a linear one's
        (its position, its sensor's offset in mm) on a rotary joint. Called by each plant, so a
        drift that would do nothing is refused rather than ignored."""
        rotary_only = ("model", "neutral_angle_deg", "initial_angle_deg", "leak", "friction_scale",
                       "sensor_offset_deg", "regulator_gain")
        linear_only = ("initial_position_mm", "sensor_offset_mm")
        default = SimJointOptions()
        for key in rotary_only if linear else linear_only:
            if getattr(self, key) != getattr(default, key):
                owner, kind = ("a rotary joint's", "a linear axis") if linear else \
                    ("a linear joint's", "a rotary joint")
                raise ConfigError(f"transport.options.joints.{joint}.{key}: {owner} option; {joint} is {kind} "
                                  f"(docs/simulator.md, Drift)")

    @property
    def drifts(self) -> bool:
        """Whether any drift is asked for."""
        return bool(self.leak) or self.friction_scale != 1.0 or self.sensor_offset_deg != 0.0 \
            or self.regulator_gain != 1.0 or self.sensor_offset_mm != 0.0

    def drift_words(self) -> str:
        """The drifts asked for, in words ("" for none): what ``pneumad --check`` says."""
        said = [f"a leak in the {self.leak} chamber ({self.leak_fraction:.0%})"] if self.leak else []
        said += [f"friction x{self.friction_scale:g}"] if self.friction_scale != 1.0 else []
        said += [f"a potentiometer offset of {self.sensor_offset_deg:g} deg"] if self.sensor_offset_deg else []
        said += [f"regulator gain {self.regulator_gain:g}"] if self.regulator_gain != 1.0 else []
        said += [f"a position sensor offset of {self.sensor_offset_mm:g} mm"] if self.sensor_offset_mm else []
        return f"{', '.join(said)} from {self.fault_at_s:g} s of the plant's clock" if said else ""


@dataclass(frozen=True)
class WallOptions:
    """A compliant wall the tip can press on; the force sensor reads the contact force."""

    enabled: bool = False
    point_mm: tuple[float, ...] = (0.0, 250.0)  # a point on the wall surface [mm]
    normal: tuple[float, ...] = (0.0, -1.0)  # unit normal pointing out of the wall, into free space
    stiffness_n_per_mm: float = 2.0

    def __post_init__(self):
        require(len(self.point_mm) == 2, "point_mm", "must be [x, y]")
        require(len(self.normal) == 2 and math.hypot(*self.normal) > 0, "normal", "must be a non-zero [x, y]")
        require(self.stiffness_n_per_mm > 0, "stiffness_n_per_mm", "must be > 0")


@dataclass(frozen=True)
class PayloadOptions:
    """A payload at the tip (rig-facts §4): its mass and centre of mass in the last link's
    frame (along it, across it, from the tip), under the rig's ``arm.gravity_m_s2``."""

    mass_kg: float = 0.0
    com_mm: tuple[float, ...] = (0.0, 0.0)

    def __post_init__(self):
        require(0.0 <= self.mass_kg <= 10.0, "mass_kg", f"must be within 0-10 kg, got {self.mass_kg}")
        require(len(self.com_mm) == 2, "com_mm", "two numbers: along and across the last link [mm]")


@dataclass(frozen=True)
class SimOptions:
    seed: int = 0
    step_s: float = 0.001  # plant step [s]
    friction: bool = True
    # "stribeck": [2-45] as identified, the smooth sign tanh(beta w / vs) (default); "karnopp":
    # exact sticking within Fs (Karnopp's model), for stick-slip studies (docs/simulator.md)
    friction_model: str = "stribeck"
    dead_time: bool = True
    supply_mpa: float = 1.0  # regulator supply pressure [MPa]
    supply_volts: float = 5.0  # potentiometer supply [V]
    adc_bits: int = 16
    dac_bits: int = 16
    adc_noise_volts: float = 0.0  # standard deviation of seeded Gaussian noise on every input [V]
    max_catch_up_s: float = 30.0  # real-time mode: the plant catches up a stall this long; a longer one pauses it
    # real-time mode: "realtime", the plant steps in a thread beside the loop, as a DAQ samples on
    # its own processor (sim_backend/plant_thread.py), when the loop runs at a real-time priority
    # for the thread to take, else in each of the loop's reads; "always"; "never"
    beside_loop: str = "realtime"
    # the cylinder arm's step compiled (sim_backend/compiled_plant.py): equal to float rounding,
    # several times faster; for evaluations (pneumactl evaluate). Stribeck friction, no payload or wall.
    compiled: bool = False
    joints: dict[str, SimJointOptions] = field(default_factory=dict)
    wall: WallOptions = WallOptions()
    payload: PayloadOptions = PayloadOptions()
    muscle: MusclePlantOptions = MusclePlantOptions()  # the muscle rig's dynamics (rig-facts §2)

    def __post_init__(self):
        require(self.friction_model in FRICTION_MODELS, "friction_model",
                f"must be one of {', '.join(FRICTION_MODELS)}, got {self.friction_model!r}")
        require(0 < self.step_s <= 0.01, "step_s", f"must be within (0, 0.01] s, got {self.step_s}")
        require(0 <= self.supply_mpa <= 1.0, "supply_mpa", "must be within 0-1.0 MPa (ITV0051 maximum)")
        require(0 < self.supply_volts <= 10, "supply_volts", "must be within (0, 10] V")
        require(2 <= self.adc_bits <= 24, "adc_bits", "must be within 2-24")
        require(2 <= self.dac_bits <= 24, "dac_bits", "must be within 2-24")
        require(self.adc_noise_volts >= 0, "adc_noise_volts", "must be >= 0")
        require(self.max_catch_up_s >= self.step_s, "max_catch_up_s", "must be at least one step")
        require(self.beside_loop in BESIDE_LOOP, "beside_loop",
                f"must be one of {', '.join(BESIDE_LOOP)}, got {self.beside_loop!r}")
