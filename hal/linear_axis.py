"""The linear pneumatic servo axis (rig-facts §5): a double-acting cylinder on a 5/3 proportional
directional valve (the Festo MPYE kind), its parameters and its physics without time stepping.

Model (Richer & Hurmuzlu, "A High Performance Pneumatic Force Actuator System: Part I",
ASME J. Dyn. Sys. Meas. Control 122(3):416-425, 2000; "R&H" below), SI inside (m, Pa absolute,
kg, s), the valve command in volts at the edge:

- orifice mass flow, sonic or subsonic by the pressure ratio (R&H's valve flow equations,
  Sanville's isentropic-nozzle form): with r = p_down / p_up and P_CR = (2/(k+1))^(k/(k-1)),
  ``m_dot = Cf A C1 p_up / sqrt(T)`` when r <= P_CR (choked), otherwise
  ``m_dot = Cf A C2 p_up / sqrt(T) r^(1/k) sqrt(1 - r^((k-1)/k))``,
  C1 = sqrt(k/R (2/(k+1))^((k+1)/(k-1))), C2 = sqrt(2k / (R (k-1))), k = 1.4 through the orifice;
  within 0.5 % of equal pressures (r > R_LAMINAR) the flow is linear in the difference
  (**interpretation**: the square-root law's slope is infinite at r = 1; Simscape's ISO 6358
  orifice takes a linear laminar region from a ratio of 0.995-0.999 for the same reason);
- valve: spool s = (V - 5 V) / 5 V in [-1, 1]; s > 0 opens supply -> head and rod -> exhaust,
  s < 0 supply -> rod and head -> exhaust. Each metering edge's effective area is
  ``Cf A(s) = A_full (s + sqrt(s^2 + s_L^2)) / (1 + sqrt(1 + s_L^2))`` (**interpretation**: a
  smooth underlap, so the null has the small leakage a real spool shows (Eryilmaz & Wilson,
  ASME JDSMC 122(3), 2000: leakage dominates near null) and it falls as a land covers its port;
  A_full is derived from the catalogue's nominal flow, :attr:`AxisParams.orifice_area_m2`);
- chambers (R&H's chamber pressure equation, with one exponent n for R&H's alpha_in, alpha_out,
  alpha): ``p_i' = n / V_i (R T m_dot_i - p_i V_i')``, V_head = V0_head + A_head x,
  V_rod = V0_rod + A_rod (stroke - x), x from the fully retracted end;
- piston (R&H's equation of motion): ``(M_p + M_L) x'' = p_head A_head - p_rod A_rod - p_atm A_r
  + F_load - beta x' - F_f(x')`` with the Coulomb/Stribeck map
  ``F_f = (Fc + (Fs - Fc) exp(-(v / vs)^2)) sgn(v)`` (Olsson et al., Eur. J. Control 4, 1998)
  and stiction at rest up to Fs; inelastic end stops at 0 and the stroke.

The time stepping is :mod:`hal.axis_model`; the linearisation and a controller's figures
are :mod:`hal.linear_axis_facts`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

from hal.schema import build, require

K_FLOW = 1.4  # ratio of specific heats of air through the orifice (isentropic nozzle, R&H)
R_AIR = 287.0  # specific gas constant of air [J/(kg K)]
P_CR = (2.0 / (K_FLOW + 1.0)) ** (K_FLOW / (K_FLOW - 1.0))  # critical pressure ratio, 0.528
C1 = math.sqrt(K_FLOW / R_AIR * (2.0 / (K_FLOW + 1.0)) ** ((K_FLOW + 1.0) / (K_FLOW - 1.0)))  # [s sqrt(K)/m]
C2 = math.sqrt(2.0 * K_FLOW / (R_AIR * (K_FLOW - 1.0)))  # [s sqrt(K)/m]
EXPONENT = (K_FLOW - 1.0) / K_FLOW
R_LAMINAR = 0.995  # above this pressure ratio the flow is linear in the pressure difference
RHO_ANR = 1.185  # air density at ISO 8778's reference atmosphere (100 kPa, 20 degC, 65 % RH) [kg/m^3]
VALVE_CENTRE_V, VALVE_MAX_V = 5.0, 10.0  # MPYE: 0-10 V command, 5 V closed mid-position (catalogue)
NOMINAL_INLET_GAUGE_PA, NOMINAL_DROP_PA = 0.6e6, 0.1e6  # the standard nominal flow's test point (6 -> 5 bar)


def _phi(r: float) -> float:
    """r^(1/k) sqrt(1 - r^((k-1)/k)): the subsonic flow's shape (R&H)."""
    t = r ** EXPONENT
    return r / t * math.sqrt(1.0 - t)


PHI_LAMINAR = _phi(R_LAMINAR)
LAMINAR_SLOPE = C2 * PHI_LAMINAR / (1.0 - R_LAMINAR)  # flow per (area/sqrt(T)) per Pa of difference


def flow_into(g: float, p_port: float, p: float) -> tuple[float, float]:
    """Mass flow [kg/s] from a port at ``p_port`` into a volume at ``p`` [Pa abs] through an
    edge of effective area over sqrt(T) ``g`` [m^2/sqrt(K)], negative when it flows out; and
    its derivative in ``p`` [kg/(s Pa)] (what the implicit step and the linearisation need)."""
    if p_port >= p:
        up, down, sign = p_port, p, 1.0
    else:
        up, down, sign = p, p_port, -1.0
    r = down / up
    if r <= P_CR:  # choked: sonic at the throat, independent of the downstream pressure
        m, d_up, d_down = g * C1 * up, g * C1, 0.0
    elif r < R_LAMINAR:
        t = r ** EXPONENT
        phi = r / t * math.sqrt(1.0 - t)
        d_phi = phi / r * (1.0 / K_FLOW - 0.5 * EXPONENT * t / (1.0 - t))
        m = g * C2 * up * phi
        d_up, d_down = g * C2 * (phi - r * d_phi), g * C2 * d_phi
    else:
        s = g * LAMINAR_SLOPE
        m, d_up, d_down = s * (up - down), s, -s
    return (m, d_down) if sign > 0.0 else (-m, -d_up)


def mass_flow(area_m2: float, p_up: float, p_down: float, temperature_k: float) -> float:
    """Mass flow [kg/s] through an orifice of effective area Cf A from ``p_up`` to ``p_down``
    [Pa abs] (negative if it flows back)."""
    return flow_into(area_m2 / math.sqrt(temperature_k), p_up, p_down)[0]


@dataclass(frozen=True)
class AxisParams:
    """One linear axis; every key carries its unit. Sources: docs/simulator.md, "The linear axis"."""

    bore_m: float = 0.025  # Festo DSNU-25 (catalogue)
    rod_m: float = 0.010  # DSNU-25 piston rod (catalogue)
    stroke_m: float = 0.200  # a standard DSNU-25 stroke (catalogue)
    dead_volume_head_m3: float = 1.0e-5  # cylinder end + 0.5 m of 4 mm bore tubing (interpretation)
    dead_volume_rod_m3: float = 1.0e-5  # the same on the rod side (interpretation)
    piston_mass_kg: float = 0.2  # piston and rod (interpretation)
    load_mass_kg: float = 1.0  # the carriage it moves (interpretation)
    load_force_n: float = 0.0  # a constant force along +x on the load, e.g. its weight on a vertical axis
    viscous_n_s_m: float = 50.0  # beta (interpretation)
    coulomb_n: float = 15.0  # Fc (interpretation)
    static_n: float = 25.0  # Fs, the breakaway force (interpretation)
    stribeck_velocity_m_s: float = 0.01  # vs (interpretation)
    supply_gauge_pa: float = 0.6e6  # 6 bar gauge (rig-facts §5)
    atmosphere_pa: float = 101_325.0
    temperature_k: float = 293.15
    polytropic: float = 1.2  # n, R&H's heat-transfer exponent alpha for the chambers
    nominal_flow_l_min: float = 700.0  # MPYE-5-1/8-HF standard nominal flow (catalogue)
    null_leak_fraction: float = 0.01  # each edge's area at 5 V over its full opening (interpretation)
    valve_time_constant_s: float = 0.002  # the spool's lag (interpretation)

    def __post_init__(self):
        for f in fields(self):
            require(math.isfinite(getattr(self, f.name)), f.name, f"must be finite, got {getattr(self, f.name)}")
        require(0.005 <= self.bore_m <= 0.5, "bore_m", f"must be within 5-500 mm, got {self.bore_m} m")
        require(0.0 <= self.rod_m < self.bore_m, "rod_m", f"must be >= 0 and below the bore {self.bore_m} m")
        require(0.005 <= self.stroke_m <= 5.0, "stroke_m", f"must be within 5 mm - 5 m, got {self.stroke_m} m")
        for name in ("dead_volume_head_m3", "dead_volume_rod_m3"):
            require(1e-9 <= getattr(self, name) <= 1e-2, name, "must be within 1e-9..1e-2 m^3 (a closed chamber "
                    "needs a volume at its stop)")
        require(self.piston_mass_kg + self.load_mass_kg > 0 and self.piston_mass_kg >= 0
                and self.load_mass_kg >= 0, "load_mass_kg", "masses must be >= 0 with a positive sum")
        require(self.viscous_n_s_m >= 0, "viscous_n_s_m", "must be >= 0")
        require(0 <= self.coulomb_n <= self.static_n, "static_n", f"must be >= coulomb_n >= 0 (Fs >= Fc), got "
                f"Fs {self.static_n}, Fc {self.coulomb_n}")
        require(self.stribeck_velocity_m_s > 0, "stribeck_velocity_m_s", "must be > 0")
        require(0.05e6 <= self.supply_gauge_pa <= 1.6e6, "supply_gauge_pa", "must be within 0.05-1.6 MPa")
        require(50e3 <= self.atmosphere_pa <= 120e3, "atmosphere_pa", "must be within 50-120 kPa")
        require(200.0 <= self.temperature_k <= 400.0, "temperature_k", "must be within 200-400 K")
        require(1.0 <= self.polytropic <= 1.4, "polytropic", "must be within 1.0 (isothermal) - 1.4 (adiabatic)")
        require(1.0 <= self.nominal_flow_l_min <= 20000.0, "nominal_flow_l_min", "must be within 1-20000 l/min")
        require(1e-6 <= self.null_leak_fraction <= 0.2, "null_leak_fraction", "must be within 1e-6..0.2")
        require(1e-4 <= self.valve_time_constant_s <= 0.1, "valve_time_constant_s", "must be within 0.1-100 ms")

    @classmethod
    def from_table(cls, table: dict, path: str = "") -> "AxisParams":
        """From a TOML table; an unknown key, a missing or wrong-typed value is a ConfigError naming it."""
        return build(cls, table, path)

    @property
    def area_head(self) -> float:
        """A_head = pi bore^2 / 4 [m^2]."""
        return math.pi * self.bore_m ** 2 / 4.0

    @property
    def area_rod_section(self) -> float:
        """A_r = pi rod^2 / 4 [m^2]: the rod's section, under the atmosphere on its outside."""
        return math.pi * self.rod_m ** 2 / 4.0

    @property
    def area_rod(self) -> float:
        """A_rod = A_head - A_r [m^2], the rod side's annulus."""
        return self.area_head - self.area_rod_section

    @property
    def supply_pa(self) -> float:
        """The supply's absolute pressure [Pa]."""
        return self.supply_gauge_pa + self.atmosphere_pa

    @property
    def moving_mass_kg(self) -> float:
        return self.piston_mass_kg + self.load_mass_kg

    @property
    def orifice_area_m2(self) -> float:
        """Cf A of one fully open metering edge [m^2], from the nominal flow: the mass flow
        rho_ANR q_nN through the flow law above at the standard test point (6 bar gauge in,
        1 bar drop), at ``temperature_k``."""
        m_dot = RHO_ANR * self.nominal_flow_l_min * 1e-3 / 60.0
        p_in = NOMINAL_INLET_GAUGE_PA + self.atmosphere_pa
        return m_dot / mass_flow(1.0, p_in, p_in - NOMINAL_DROP_PA, self.temperature_k)

    @property
    def underlap(self) -> float:
        """s_L of the edge area, from the null leak fraction f = s_L / (1 + sqrt(1 + s_L^2))."""
        f = self.null_leak_fraction
        return 2.0 * f / (1.0 - f * f)

    def volumes(self, position_m: float) -> tuple[float, float]:
        """(V_head, V_rod) [m^3] at a piston position [m] from the retracted end."""
        return (self.dead_volume_head_m3 + self.area_head * position_m,
                self.dead_volume_rod_m3 + self.area_rod * (self.stroke_m - position_m))


def spool_of(volts: float) -> float:
    """The spool's position the valve settles to for a command [V]: (V - 5) / 5, within [-1, 1]."""
    return min(max((volts - VALVE_CENTRE_V) / VALVE_CENTRE_V, -1.0), 1.0)


def edge_area(params: AxisParams, s: float) -> float:
    """Cf A [m^2] of an edge that opens for s > 0 (supply -> head, rod -> exhaust), at spool s;
    the other two edges have ``edge_area(params, -s)``."""
    s_l = params.underlap
    return params.orifice_area_m2 * (s + math.sqrt(s * s + s_l * s_l)) / (1.0 + math.sqrt(1.0 + s_l * s_l))


def chamber_inflow(params: AxisParams, s: float, p: float, head: bool) -> tuple[float, float]:
    """Net mass flow [kg/s] into the head (or rod) chamber at pressure ``p`` through its two
    edges at spool ``s``, and its derivative in ``p`` [kg/(s Pa)]."""
    root_t = math.sqrt(params.temperature_k)
    a_in, a_out = (edge_area(params, s), edge_area(params, -s)) if head else (edge_area(params, -s),
                                                                               edge_area(params, s))
    m_in, d_in = flow_into(a_in / root_t, params.supply_pa, p)
    m_out, d_out = flow_into(a_out / root_t, params.atmosphere_pa, p)
    return m_in + m_out, d_in + d_out


def friction_magnitude(params: AxisParams, speed: float) -> float:
    """Fc + (Fs - Fc) exp(-(v/vs)^2) [N], the Stribeck map's magnitude at a speed [m/s]."""
    return params.coulomb_n + (params.static_n - params.coulomb_n) * math.exp(
        -(speed / params.stribeck_velocity_m_s) ** 2)


@dataclass(frozen=True)
class AxisState:
    """The axis's state: piston position [m] from the retracted end, velocity [m/s], chamber
    pressures [Pa abs], and the spool's normalised position (-1..1, 0 = closed centre)."""

    position_m: float
    velocity_m_s: float
    p_head_pa: float
    p_rod_pa: float
    spool: float
