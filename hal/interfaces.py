"""The interfaces a rig declares, after ros2_control's hardware description: per joint, its
kind, what it reports (state interfaces) and what it is commanded with (command interfaces);
per rig, the sensors no joint owns.

Everything that follows the rig (the cycle record's layout, telemetry, recordings, status,
``describe``, plots, the Bluesky signals) is built from a :class:`RigInterfaces`, never from a
list of fields written by hand. SI units inside (rad or m, Pa, N, V at the hardware edge);
each interface also says how a person reads it (``display``: deg for rad, mm for m, kPa for Pa).

- a **rotary** joint's position is in rad (shown in deg); a **linear** joint's in m (shown in mm);
- a joint's state interfaces: ``position``, ``velocity`` (the loop's filtered difference), each
  chamber's pressure where a transmitter is wired (``p_<chamber>``: ``p_head``, ``p_rod`` on a
  cylinder, ``p_a``, ``p_b`` on a muscle pair), and any further analog input by its own name;
- a joint's command interfaces (:class:`CommandInterface`, what a controller's output vector
  holds, in order): ``v_mv`` [V] (a regulator pair about its bias), ``pressure_a``/``pressure_b``
  [Pa] and ``brake`` [N m] (a muscle pair), ``valve`` [V] (a 5/3 proportional directional valve
  about its centre);
- a joint whose actuation commands chamber pressures (regulators, a muscle pair's valves) also
  has commanded pressures, ``p_<chamber>_cmd`` [Pa]: what its devices were told, after the
  clamps; measured and commanded pressures never share a name;
- rig-level state: ``force`` [N] (a force sensor), ``supply_pressure`` [Pa], spare analog inputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

ROTARY, LINEAR = "rotary", "linear"
# SI unit -> (the unit a person reads, its scale): what watch, status, plots, PlotJuggler and the Bluesky
# signals show; the wire, recordings and CSV exports keep SI. Pressures in kPa, as the lab's gauges read.
DISPLAY = {"rad": ("deg", 180.0 / math.pi), "rad/s": ("deg/s", 180.0 / math.pi),
           "m": ("mm", 1000.0), "m/s": ("mm/s", 1000.0), "Pa": ("kPa", 1e-3)}
POSITION_UNIT = {ROTARY: "rad", LINEAR: "m"}


@dataclass(frozen=True)
class StateInterface:
    """One value the rig reports each cycle: whose (a joint's name, "" for the rig), its name,
    SI unit and plausible range."""

    owner: str
    name: str
    unit: str
    low: float = -math.inf
    high: float = math.inf
    doc: str = ""

    @property
    def display(self) -> tuple[str, float]:
        """(unit, scale) a person reads it in: deg for rad, mm for m, kPa for Pa, else the SI unit itself."""
        return DISPLAY.get(self.unit, (self.unit, 1.0))

    def describe(self) -> dict:
        unit, scale = self.display
        return {"owner": self.owner, "name": self.name, "unit": self.unit, "low": _finite(self.low),
                "high": _finite(self.high), "display_unit": unit, "display_scale": scale, "doc": self.doc}


@dataclass(frozen=True)
class CommandInterface:
    """One value a controller commands: its joint, name, unit and range."""

    joint: str
    name: str
    unit: str
    low: float
    high: float

    def describe(self) -> dict:
        return {"joint": self.joint, "name": self.name, "unit": self.unit, "low": self.low, "high": self.high}


@dataclass(frozen=True)
class JointInterfaces:
    """One joint's declared interfaces."""

    name: str
    kind: str  # ROTARY or LINEAR
    actuation: str  # "cylinder", "muscle_pair", "valve" (hal.config)
    chambers: tuple[str, ...]  # e.g. ("head", "rod"), ("a", "b")
    state: tuple[StateInterface, ...]  # position and velocity first, then pressures and inputs
    commands: tuple[CommandInterface, ...]
    commanded_pressures: tuple[str, ...] = ()  # chambers whose pressure the actuation commands

    @property
    def position_unit(self) -> str:
        return POSITION_UNIT[self.kind]

    def measured(self) -> tuple[StateInterface, ...]:
        """The state interfaces read from sensors besides position and velocity."""
        return self.state[2:]


@dataclass(frozen=True)
class RigInterfaces:
    joints: tuple[JointInterfaces, ...]
    rig: tuple[StateInterface, ...]  # sensors no joint owns: force, supply pressure, spare inputs
    outputs: tuple[str, ...]  # the transport's output channels, in sweep order (their volts are recorded)

    @property
    def commands(self) -> tuple[CommandInterface, ...]:
        """Every joint's command interfaces in joint order: a controller's output vector."""
        return tuple(c for j in self.joints for c in j.commands)

    def joint(self, name: str) -> JointInterfaces:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(name)


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
