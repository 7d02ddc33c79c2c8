"""Identified models of the cylinder joints, rig-facts §1 (table "Identified values").

They are a fact of the rig, so they live in its configuration: ``[models.NAME]`` tables,
the built-in ones in ``hal/models.toml`` (the thesis's values), a rig file's own beside them
(what ``pneumactl identify`` writes). The simulator takes a joint's model as its true plant,
model-based controllers as their nominal plant (``[[joints]] model`` names the set per
joint, and the simulator's options can name another, so the two can differ on purpose).

**Units.** As rig-facts §1 "Units" argues, the fit was made with the joint angle in degrees:
th [deg], th' [deg/s], J [N m s^2/deg], D [N m s/deg], K [N m/deg], Fs, Fc [N m],
vs [deg/s]. Torques (L F, friction) are in N m. The simulator works in these model units
internally and converts to SI (rad) at its edges; :mod:`controllers.nominal` converts to SI.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from importlib import resources

K_EP = 0.0899e6  # regulator slope [Pa/V], [2-29]
P_OFFSET = 0.001e6  # regulator pressure at 0 V [Pa], [2-29]
P_SET_MIN, P_SET_MAX = 0.001e6, 0.9e6  # regulator set range [Pa]
SUPPLY_HEADROOM = 0.1e6  # supply must exceed the set pressure by this [Pa]


@dataclass(frozen=True)
class JointParams:
    """One joint's identified model [2-36..2-39, 2-45, 2-50] and its cylinder geometry."""

    K_mdl: float  # model gain [-]
    L: float  # effective moment arm [m]
    J: float  # inertia [N m s^2/deg]
    D: float  # viscous friction [N m s/deg]
    K: float  # spring about the neutral angle [N m/deg]
    T_ep: float  # regulator lag [s]
    T_dly: float  # input dead time [s]
    Fs: float  # static (breakaway) friction [N m]
    Fc: float  # Coulomb friction [N m]
    vs: float  # Stribeck velocity [deg/s]
    alpha: float  # Stribeck shape exponent [-]
    beta: float  # smooth-sign sharpness, sgn(w) ~ tanh(beta w / vs) (interpretation) [-]
    bore: float  # cylinder bore [m]
    rod: float  # piston-rod diameter [m]
    stroke: float  # [m]

    @property
    def area_head(self) -> float:
        """A_H = pi bore^2 / 4 [m^2]."""
        return math.pi * self.bore ** 2 / 4.0

    @property
    def area_rod(self) -> float:
        """A_L = pi (bore^2 - rod^2) / 4 [m^2]."""
        return math.pi * (self.bore ** 2 - self.rod ** 2) / 4.0

    @property
    def torque_per_volt(self) -> float:
        """Head-side torque per volt of V_MV, K_mdl L A_H K_ep [N m/V] (rig-facts "Authority")."""
        return self.K_mdl * self.L * self.area_head * K_EP

    def replace(self, overrides: dict[str, float]) -> "JointParams":
        """A copy with some values replaced; an unknown name is a KeyError naming it."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise KeyError(f"unknown joint parameter {unknown[0]!r} (known: {', '.join(sorted(names))})")
        new = dataclasses.replace(self, **overrides)
        for f in dataclasses.fields(new):
            value = getattr(new, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"joint parameter {f.name} must be finite and >= 0, got {value}")
        for name in ("J", "T_ep", "vs", "bore", "L"):
            if getattr(new, name) <= 0:
                raise ValueError(f"joint parameter {name} must be > 0")
        return new


UNITS = {"K_mdl": "-", "L": "m", "J": "N m s^2/deg", "D": "N m s/deg", "K": "N m/deg", "T_ep": "s", "T_dly": "s",
         "Fs": "N m", "Fc": "N m", "vs": "deg/s", "alpha": "-", "beta": "-", "bore": "m", "rod": "m", "stroke": "m"}
TABLE_KEYS = ("source", "based_on")  # a model table's keys beside the parameters
# what an identification says of its model (``pneumactl identify`` writes them): the [2-49] Fit
# and the residual's RMS on data the fit did not see; the model beside the arm derives its band
# from the RMS (controllers.drift.band_of)
IDENTIFICATION_KEYS = {"heldout_fit_percent": "%", "heldout_rms_deg": "deg"}


def parse_models(tables: dict, known: dict[str, JointParams] | None = None) -> dict[str, JointParams]:
    """``[models.NAME]`` tables -> parameter sets. A table gives every parameter, or names
    ``based_on`` (a built-in or an earlier table) and gives what differs; ``source`` says where
    its numbers came from. ValueError names the table and the key."""
    out: dict[str, JointParams] = {}
    names = [f.name for f in dataclasses.fields(JointParams)]
    for name, table in tables.items():
        where = f"models.{name}"
        if not isinstance(table, dict):
            raise ValueError(f"{where}: expected a table")
        unknown = sorted(set(table) - set(names) - set(TABLE_KEYS) - set(IDENTIFICATION_KEYS))
        if unknown:
            allowed = names + list(TABLE_KEYS) + list(IDENTIFICATION_KEYS)
            raise ValueError(f"{where}.{unknown[0]}: unknown key (allowed: {', '.join(allowed)})")
        for key in TABLE_KEYS:
            if key in table and not isinstance(table[key], str):
                raise ValueError(f"{where}.{key}: expected a string")
        identification(table, where)
        values = {k: v for k, v in table.items() if k not in TABLE_KEYS and k not in IDENTIFICATION_KEYS}
        for key, v in values.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{where}.{key}: expected a number [{UNITS[key]}], got {v!r}")
        base_name = table.get("based_on")
        try:
            if base_name is not None:
                base = out.get(base_name) or (known or {}).get(base_name)
                if base is None:
                    raise ValueError(f"based_on: no model {base_name!r} (known: {', '.join([*(known or {}), *out])})")
                out[name] = base.replace({k: float(v) for k, v in values.items()})
            else:
                missing = [n for n in names if n not in values]
                if missing:
                    raise ValueError(f"{missing[0]}: missing (give every parameter, or based_on = \"NAME\")")
                out[name] = JointParams(**{k: float(v) for k, v in values.items()}).replace({})
        except (KeyError, ValueError) as exc:
            raise ValueError(f"{where}: {str(exc).strip(chr(39))}") from None
    return out


def identification(table: dict, where: str = "models") -> dict[str, float]:
    """A model table's IDENTIFICATION_KEYS (its own, not a ``based_on``'s: a model changed from
    an identified one is not what was judged); ValueError for one that is not a finite number
    (the RMS also > 0; a Fit may be negative: a model worse than the mean)."""
    out = {}
    for key, unit in IDENTIFICATION_KEYS.items():
        if key in table:
            v = table[key]
            number = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
            if not number or (key == "heldout_rms_deg" and v <= 0):
                kind = "a number > 0" if key == "heldout_rms_deg" else "a number"
                raise ValueError(f"{where}.{key}: expected {kind} [{unit}], got {v!r}")
            out[key] = float(v)
    return out


IDENTIFIED: dict[str, JointParams] = parse_models(tomllib.loads(resources.files("hal").joinpath("models.toml")
                                                                .read_text())["models"])
