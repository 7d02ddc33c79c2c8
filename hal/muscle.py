"""The antagonistic artificial-muscle joint's statics (rig-facts §2): muscle force, the pair's
torque and stiffness, and the mechanical-equilibrium model [4.17, 4.18] that gives the two
muscle pressures for a desired angle, stiffness and load torque.

**Interpretation** (the chapter's own force equations are not legible): each muscle follows
the static model of Tondu & Lopez (IEEE Control Systems Magazine 20(2), 2000) for a
braided (McKibben) muscle, which also describes a straight-fibre muscle's shape over its
working range::

    F(P, eps) = P * pi r0^2 * (a (1 - k eps)^2 - b),   a = 3 / tan^2(alpha0),  b = 1 / sin^2(alpha0)

with P the gauge pressure [Pa], eps the contraction ratio, r0 the rest radius [m], alpha0 the
braid (fibre) angle at rest and k >= 1 Tondu's end-effect factor; a muscle only pulls (F >= 0).
The force is linear in P, so the pair's torque and stiffness are linear in (P_a, P_b) and the
equilibrium model is a 2 x 2 linear solve. Geometry: muscle a (flexor) contracts as the
joint angle theta grows, over a pulley of radius R::

    eps_a = eps_c + R (theta - theta_c) / L0,    eps_b = eps_c - R (theta - theta_c) / L0
    tau   = n R (F_a - F_b)                                  [N m]
    K     = -d tau / d theta = n R^2 / L0 (P_a |g'(eps_a)| + P_b |g'(eps_b)|)   [N m/rad]

with n muscles in parallel per side. SI throughout: rad, m, Pa, N, N m.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.schema import require

P_ATM = 101_325.0  # [Pa]


@dataclass(frozen=True)
class MuscleConfig:
    """The pair's muscles and their mounting: ``[joints.muscles]`` in a rig file."""

    rest_length_mm: float = 200.0  # L0
    rest_radius_mm: float = 6.0  # r0
    fibre_angle_deg: float = 18.0  # alpha0
    end_factor: float = 1.0  # Tondu's k
    per_side: int = 2  # muscles in parallel per side (rig-facts §2: two)
    pulley_radius_mm: float = 30.0  # R
    centre_angle_deg: float = 45.0  # theta_c: where both muscles are contracted alike ...
    centre_contraction: float = 0.15  # ... by this much (eps_c, set by the mounting)
    tube_volume_cm3: float = 5.0  # the line and fittings of each side [cm^3]

    def __post_init__(self):
        require(self.rest_length_mm > 0, "rest_length_mm", "must be > 0")
        require(self.rest_radius_mm > 0, "rest_radius_mm", "must be > 0")
        require(5.0 <= self.fibre_angle_deg <= 54.0, "fibre_angle_deg",
                "must be within 5-54 deg (at 54.7 deg a braided muscle makes no force)")
        require(1.0 <= self.end_factor <= 2.0, "end_factor", "must be within 1-2")
        require(1 <= self.per_side <= 8, "per_side", "must be within 1-8")
        require(self.pulley_radius_mm > 0, "pulley_radius_mm", "must be > 0")
        require(0.0 <= self.centre_contraction < 0.4, "centre_contraction", "must be within 0-0.4")
        require(self.tube_volume_cm3 >= 0, "tube_volume_cm3", "must be >= 0")


class MusclePair:
    """The statics of one antagonistic pair; pure functions of (pressures, angle)."""

    def __init__(self, config: MuscleConfig):
        self.config = config
        alpha = math.radians(config.fibre_angle_deg)
        self.a = 3.0 / math.tan(alpha) ** 2
        self.b = 1.0 / math.sin(alpha) ** 2
        self.k = config.end_factor
        self.area = math.pi * (config.rest_radius_mm * 1e-3) ** 2  # pi r0^2 [m^2]
        self.length = config.rest_length_mm * 1e-3  # L0 [m]
        self.radius = config.pulley_radius_mm * 1e-3  # R [m]
        self.n = config.per_side
        self.theta_c = math.radians(config.centre_angle_deg)
        self.eps_c = config.centre_contraction
        # the contraction at which a muscle stops pulling: a (1 - k eps)^2 = b
        self.eps_max = (1.0 - math.sqrt(self.b / self.a)) / self.k

    # -- one muscle --------------------------------------------------------------------
    def contractions(self, theta: float) -> tuple[float, float]:
        d = self.radius * (theta - self.theta_c) / self.length
        return self.eps_c + d, self.eps_c - d

    def gain(self, eps: float) -> float:
        """g(eps) = F / P [m^2]: 0 once the muscle is contracted past eps_max (it goes slack)."""
        s = 1.0 - self.k * eps
        g = self.area * (self.a * s * s - self.b)
        return g if g > 0.0 else 0.0

    def slope(self, eps: float) -> float:
        """-dg/deps [m^2] (>= 0: force falls as the muscle contracts)."""
        if eps >= self.eps_max:
            return 0.0
        return 2.0 * self.area * self.a * self.k * (1.0 - self.k * eps)

    def volume(self, eps: float) -> float:
        """One muscle's volume [m^3]: V0 + L0 * integral of g, so that F = P dV/d(stroke)
        (virtual work); constant past eps_max."""
        e = min(max(eps, -0.2), self.eps_max)
        k = self.k
        swept = self.a * (1.0 - (1.0 - k * e) ** 3) / (3.0 * k) - self.b * e
        return self.area * self.length * (1.0 + swept)

    # -- the pair ----------------------------------------------------------------------
    def torque(self, p_a: float, p_b: float, theta: float) -> float:
        """The muscles' torque on the joint [N m] at gauge pressures [Pa] (negative ones pull nothing)."""
        ea, eb = self.contractions(theta)
        return self.n * self.radius * (max(p_a, 0.0) * self.gain(ea) - max(p_b, 0.0) * self.gain(eb))

    def stiffness(self, p_a: float, p_b: float, theta: float) -> float:
        """K = -d torque / d theta [N m/rad] at fixed pressures."""
        ea, eb = self.contractions(theta)
        return self.n * self.radius ** 2 / self.length * (max(p_a, 0.0) * self.slope(ea) + max(p_b, 0.0) * self.slope(eb))

    def equilibrium(self, theta: float, stiffness: float, torque: float) -> tuple[float, float]:
        """[4.17, 4.18]: the gauge pressures (P_a, P_b) [Pa] at which the pair holds ``torque``
        [N m] at ``theta`` [rad] with joint stiffness ``stiffness`` [N m/rad]. May return a
        negative pressure: the pair cannot do it (see :meth:`stiffness_range`)."""
        ea, eb = self.contractions(theta)
        ga, gb, sa, sb = self.gain(ea), self.gain(eb), self.slope(ea), self.slope(eb)
        t = torque / (self.n * self.radius)  # ga Pa - gb Pb
        s = stiffness * self.length / (self.n * self.radius ** 2)  # sa Pa + sb Pb
        det = ga * sb + gb * sa
        if det <= 0.0:
            return math.nan, math.nan
        return (t * sb + gb * s) / det, (ga * s - t * sa) / det

    def stiffness_range(self, theta: float, torque: float, p_max: float) -> tuple[float, float]:
        """The stiffness [N m/rad] the pair can give while holding ``torque`` at ``theta`` with
        both pressures within 0..p_max [Pa] (lo > hi: none)."""
        ea, eb = self.contractions(theta)
        ga, gb, sa, sb = self.gain(ea), self.gain(eb), self.slope(ea), self.slope(eb)
        c = self.n * self.radius ** 2 / self.length
        t = torque / (self.n * self.radius)
        if ga <= 0.0 or gb <= 0.0:
            return math.inf, -math.inf
        # along the line ga Pa - gb Pb = t, K grows with Pa; Pa, Pb within 0..p_max
        pa_lo = max(0.0, t / ga)
        pa_hi = min(p_max, (t + gb * p_max) / ga)
        if pa_lo > pa_hi:
            return math.inf, -math.inf

        def k_at(pa: float) -> float:
            return c * (pa * sa + (ga * pa - t) / gb * sb)
        return k_at(pa_lo), k_at(pa_hi)


@dataclass(frozen=True)
class MuscleJoint:
    """What a controller and the planner know of one muscle-pair joint: its pair's statics,
    the link it carries (rig-facts §2: 0.168 kg, centre of gravity 240 mm, 4.80e-3 kg m^2),
    its length to the tip, gravity in the arm's plane, and its command ranges."""

    pair: MusclePair
    link_mass_kg: float
    link_com_m: float
    inertia_kg_m2: float
    length_m: float
    gravity_m_s2: tuple[float, float]
    p_max_pa: float  # the valves' and the rig's pressure ceiling
    brake_max_nm: float  # 0 without a brake

    @classmethod
    def from_rig(cls, rig, joint) -> "MuscleJoint":
        i = [j.name for j in rig.joints].index(joint.name)
        p_max = min(rig.limits.max_pressure_mpa, joint.valve_a.max_mpa, joint.valve_b.max_mpa) * 1e6
        return cls(MusclePair(joint.muscles), joint.link.mass_kg, joint.link.com_mm * 1e-3, joint.link.inertia_kg_m2,
                   rig.arm.link_lengths_m[i], tuple(rig.arm.gravity_m_s2), p_max,
                   joint.brake.max_nm if joint.brake is not None else 0.0)

    def tip_mass_kg(self, tip_load_n: float) -> float:
        """The mass [kg] whose weight under the rig's gravity is a tip load [N] (none without gravity)."""
        g = math.hypot(*self.gravity_m_s2)
        return tip_load_n / g if g > 0 else 0.0

    def gravity_torque(self, theta: float, tip_load_n: float = 0.0) -> float:
        """Gravity's torque on the joint [N m] from the link and a tip load's weight [N]
        (a single joint: the link points along (cos theta, sin theta) of the arm's plane)."""
        gx, gy = self.gravity_m_s2
        moment = self.link_mass_kg * self.link_com_m + self.tip_mass_kg(tip_load_n) * self.length_m
        return moment * (math.cos(theta) * gy - math.sin(theta) * gx)

    def stiffness_range(self, theta: float, tip_load_n: float = 0.0) -> tuple[float, float]:
        """The stiffness [N m/rad] the muscles can hold ``theta`` with (lo > hi: none)."""
        return self.pair.stiffness_range(theta, -self.gravity_torque(theta, tip_load_n), self.p_max_pa)
