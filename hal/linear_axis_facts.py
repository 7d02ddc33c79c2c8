"""What a controller or a feasibility check needs to know of a linear axis (:mod:`hal.linear_axis`):
its rest at the valve's null, its model linearised about a position at rest, the third-order
transfer function from valve volts to position, and its limits (top speed under the load, stall
forces, the pneumatic spring's stiffness and natural frequency).

**Linearisation** about a rest (x0, v = 0, p_head, p_rod, spool s0, where both chambers' flows
balance and the forces balance; Coulomb friction left out, viscous kept). From the chamber
equation and the equation of motion of :mod:`hal.linear_axis`, with m_i = the net inflow of
chamber i, state (x, v, p_head, p_rod), input the valve volts (spool lag neglected):

    x' = v
    M v' = A_h dp_h - A_r' dp_r - beta v                     (A_r' = A_rod, the annulus)
    dp_h' = n/V_h (R T (dm_h/ds ds + dm_h/dp_h dp_h) - p_h A_h v)
    dp_r' = n/V_r (R T (dm_r/ds ds + dm_r/dp_r dp_r) + p_r A_rod v)

Dropping the pressure-flow terms dm/dp (small at the null) leaves the classic third-order form
of a valve-controlled cylinder (Merritt, *Hydraulic Control Systems*, Wiley 1967, the
valve-controlled piston; with air's bulk modulus n p in place of the oil's):

    X(s) / U(s) = K_v wn^2 / (s (s^2 + 2 zeta wn s + wn^2))
    K_p = n (p_h A_h^2 / V_h + p_r A_rod^2 / V_r)      the pneumatic spring [N/m]
    wn = sqrt(K_p / M),  zeta = beta / (2 sqrt(K_p M)),  K_v = K_u / K_p [m/(s V)]
    K_u = n R T (A_h dm_h/ds / V_h - A_rod dm_r/ds / V_r) / 5 V   [N/(s V)]

The full four-state model keeps dm/dp (it damps the spring) and is what :func:`linearise` returns
beside the third-order figures.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from hal.linear_axis import (
    VALVE_CENTRE_V,
    AxisParams,
    AxisState,
    R_AIR,
    chamber_inflow,
    friction_magnitude,
)

_TOL = 1e-12


def balance_pressure(params: AxisParams, s: float, head: bool) -> float:
    """The pressure [Pa abs] at which a still chamber's two edges pass equal flows at spool s
    (its pressure at rest, whatever its volume)."""
    return brentq(lambda p: chamber_inflow(params, s, p, head)[0], 0.5 * params.atmosphere_pa,
                  params.supply_pa, xtol=1e-6, rtol=_TOL)


def _net_force_at_rest(params: AxisParams, s: float) -> float:
    """Net force [N] on the still piston with both chambers at their balance pressures."""
    return (params.area_head * balance_pressure(params, s, True) - params.area_rod * balance_pressure(params, s, False)
            - params.atmosphere_pa * params.area_rod_section + params.load_force_n)


def null_spool(params: AxisParams) -> float:
    """The spool position (-1..1) that holds the piston still with friction aside: the chambers'
    flows balance and so do the forces. A differential cylinder's is not 0 (at 5 V both chambers
    leak to the same pressure and the head's larger area pushes): a real axis's null offset.
    ValueError if the load is beyond what the axis can hold."""
    lo, hi = _net_force_at_rest(params, -1.0), _net_force_at_rest(params, 1.0)
    if lo > 0.0 or hi < 0.0:
        raise ValueError(f"load_force_n {params.load_force_n} N: beyond what the axis can hold (net force "
                         f"{lo:.1f} N fully retracting, {hi:.1f} N fully extending)")
    return brentq(lambda s: _net_force_at_rest(params, s), -1.0, 1.0, xtol=1e-12, rtol=_TOL)


def null_volts(params: AxisParams) -> float:
    """The valve command [V] that holds the axis still (:func:`null_spool`)."""
    return VALVE_CENTRE_V * (1.0 + null_spool(params))


def rest_state(params: AxisParams, position_m: float | None = None) -> AxisState:
    """The axis at rest at a position [m] (default mid-stroke) with the valve at its null."""
    x = 0.5 * params.stroke_m if position_m is None else position_m
    if not 0.0 <= x <= params.stroke_m:
        raise ValueError(f"position {x} m: outside the stroke 0..{params.stroke_m} m")
    s = null_spool(params)
    return AxisState(x, 0.0, balance_pressure(params, s, True), balance_pressure(params, s, False), s)


@dataclass(frozen=True)
class LinearAxis:
    """The axis linearised about a rest: (A, B, C) of the state (x [m], v [m/s], p_head, p_rod
    [Pa]) with the valve volts as input and x as output, and the third-order form's figures."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    rest: AxisState
    null_volts: float
    stiffness_n_m: float  # K_p, the pneumatic spring
    natural_frequency_rad_s: float  # wn
    damping_ratio: float  # zeta, from the viscous friction alone
    velocity_gain_m_s_v: float  # K_v

    def transfer_function(self) -> tuple[list[float], list[float]]:
        """(num, den) of K_v wn^2 / (s (s^2 + 2 zeta wn s + wn^2)) [m/V], highest power first."""
        wn, z = self.natural_frequency_rad_s, self.damping_ratio
        return [self.velocity_gain_m_s_v * wn * wn], [1.0, 2.0 * z * wn, wn * wn, 0.0]


def linearise(params: AxisParams, position_m: float | None = None) -> LinearAxis:
    """The model linearised about the rest at a position (default mid-stroke), see the module."""
    rest = rest_state(params, position_m)
    s0, ph, pr = rest.spool, rest.p_head_pa, rest.p_rod_pa
    vh, vr = params.volumes(rest.position_m)
    n, rt, m = params.polytropic, R_AIR * params.temperature_k, params.moving_mass_kg
    ah, ar = params.area_head, params.area_rod
    ds = 1e-7
    dmh_ds = (chamber_inflow(params, s0 + ds, ph, True)[0] - chamber_inflow(params, s0 - ds, ph, True)[0]) / (2 * ds)
    dmr_ds = (chamber_inflow(params, s0 + ds, pr, False)[0] - chamber_inflow(params, s0 - ds, pr, False)[0]) / (2 * ds)
    dmh_dp = chamber_inflow(params, s0, ph, True)[1]
    dmr_dp = chamber_inflow(params, s0, pr, False)[1]
    per_volt = 1.0 / VALVE_CENTRE_V
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [0.0, -params.viscous_n_s_m / m, ah / m, -ar / m],
                  [0.0, -n * ph * ah / vh, n * rt * dmh_dp / vh, 0.0],
                  [0.0, n * pr * ar / vr, 0.0, n * rt * dmr_dp / vr]])
    b = np.array([[0.0], [0.0], [n * rt * dmh_ds / vh * per_volt], [n * rt * dmr_ds / vr * per_volt]])
    c = np.array([[1.0, 0.0, 0.0, 0.0]])
    k_p = n * (ph * ah * ah / vh + pr * ar * ar / vr)
    k_u = n * rt * (ah * dmh_ds / vh - ar * dmr_ds / vr) * per_volt
    return LinearAxis(a, b, c, rest, VALVE_CENTRE_V * (1.0 + s0), k_p, math.sqrt(k_p / m),
                      params.viscous_n_s_m / (2.0 * math.sqrt(k_p * m)), k_u / k_p)


def steady_motion(params: AxisParams, volts: float, load_force_n: float | None = None) -> tuple[float, float, float]:
    """(speed [m/s], signed + extending; p_head, p_rod [Pa abs]) the piston tends to with the valve
    held at a command [V] and a constant load force [N] (default the params'), away from the
    stops: both chambers' pressures still (R T m_i = p_i V_i', whatever the volumes; the exponent
    drops out) and the forces in balance at Coulomb friction. Speed 0 (and the chambers' balance
    pressures) if the breakaway force holds it. The chamber being emptied approaches its pressure
    over a time of the order of the stroke's, so a short stroke ends before this speed is
    reached: it is the top speed, an upper bound."""
    s = min(max((volts - VALVE_CENTRE_V) / VALVE_CENTRE_V, -1.0), 1.0)
    load = params.load_force_n if load_force_n is None else load_force_n
    rt, ah, ar = R_AIR * params.temperature_k, params.area_head, params.area_rod
    p_top = 20.0 * params.supply_pa

    def pressure(v: float, head: bool) -> float:
        """The chamber's pressure at which its flow keeps pace with its volume change at speed v."""
        rate = ah * v if head else -ar * v  # V_i' [m^3/s]

        def excess(p: float) -> float:
            return rt * chamber_inflow(params, s, p, head)[0] - p * rate
        if excess(p_top) > 0.0:
            return p_top  # the exhaust cannot keep up: the chamber would hold the piston back
        return brentq(excess, 1.0, p_top, xtol=1e-6, rtol=_TOL)

    def force(v: float) -> float:
        drag = params.viscous_n_s_m * v + math.copysign(friction_magnitude(params, abs(v)), v)
        return (ah * pressure(v, True) - ar * pressure(v, False) - params.atmosphere_pa * params.area_rod_section
                + load - drag)

    creep = 1e-9  # [m/s]: the map's sign on either side of rest
    if force(creep) > 0.0:
        v = brentq(force, creep, 50.0, xtol=1e-12, rtol=_TOL)
    elif force(-creep) < 0.0:
        v = brentq(force, -50.0, -creep, xtol=1e-12, rtol=_TOL)
    else:
        v = 0.0  # stalled: the breakaway force holds it
    return v, pressure(v, True), pressure(v, False)


@dataclass(frozen=True)
class AxisFacts:
    """A controller's figures for one axis (SI; volts at the valve)."""

    null_volts: float
    stiffness_n_m: float  # pneumatic spring at the linearisation's position
    natural_frequency_hz: float
    damping_ratio: float
    velocity_gain_m_s_v: float  # near the null
    max_speed_extend_m_s: float  # top speed at 10 V under the load (steady_motion: an upper bound)
    max_speed_retract_m_s: float  # at 0 V under the load (a positive figure)
    stall_force_extend_n: float  # the most the axis pushes, held still at 10 V
    stall_force_retract_n: float  # the most it pulls, held still at 0 V


def facts(params: AxisParams, position_m: float | None = None) -> AxisFacts:
    """The figures of :class:`AxisFacts` at a position (default mid-stroke)."""
    lin = linearise(params, position_m)
    pa_ar = params.atmosphere_pa * params.area_rod_section

    def stall(s: float) -> float:
        return (params.area_head * balance_pressure(params, s, True)
                - params.area_rod * balance_pressure(params, s, False) - pa_ar)
    return AxisFacts(lin.null_volts, lin.stiffness_n_m, lin.natural_frequency_rad_s / (2 * math.pi),
                     lin.damping_ratio, lin.velocity_gain_m_s_v, steady_motion(params, 10.0)[0],
                     -steady_motion(params, 0.0)[0], stall(1.0), -stall(-1.0))
