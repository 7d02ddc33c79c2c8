"""Identified parameters of the cylinder joints, rig-facts §1 (table "Identified values").

They are a fact of the rig, so they live beside its configuration: the simulator takes them
as the true plant, model-based controllers as their nominal plant (a rig file names the set
per joint, ``[[joints]] model``, so the two can be made to differ on purpose).

**Units.** As rig-facts §1 "Units" argues, the fit was made with the joint angle in degrees:
th [deg], th' [deg/s], J [N m s^2/deg], D [N m s/deg], K [N m/deg], Fs, Fc [N m],
vs [deg/s]. Torques (L F, friction) are in N m. The simulator works in these model units
internally and converts to SI (rad) at its edges; :mod:`controllers.nominal` converts to SI.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

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


IDENTIFIED: dict[str, JointParams] = {
    "bottom": JointParams(K_mdl=1.034, L=5.166e-2, J=5.680e-4, D=1.880e-1, K=1.740e-2, T_ep=4.371e-2,
                          T_dly=8.117e-2, Fs=2.664e-1, Fc=8.918e-2, vs=9.919e-2, alpha=1.961, beta=1.683,
                          bore=15e-3, rod=5e-3, stroke=20e-3),
    "middle": JointParams(K_mdl=1.007, L=1.867e-2, J=1.660e-4, D=2.390e-1, K=1.315e-2, T_ep=4.277e-2,
                          T_dly=3.941e-2, Fs=2.200e-1, Fc=1.371e-2, vs=9.194e-2, alpha=1.966, beta=1.737,
                          bore=10e-3, rod=5e-3, stroke=15e-3),
}
# The top joint was never identified; it has the middle joint's cylinder, so it takes the
# middle joint's model (an assumption, stated in the built-in 3-joint rig).
IDENTIFIED["top"] = IDENTIFIED["middle"]
