"""The linear pneumatic servo axis (rig-facts §5), stepped at a fixed step: valve volts in,
piston position, velocity and chamber pressures out. The physics (Richer & Hurmuzlu 2000's
orifice flow, chamber pressure and motion equations) and the parameters are :mod:`hal.linear_axis`;
this module integrates them.

**Integration.** Each plant step (1 ms) is cut into sub-steps of at most ``MAX_SUBSTEP_S``
(0.25 ms). The pressure equation is stiff: near equal pressures the orifice's flow changes
steeply with the chamber's pressure (the laminar slope), which gives a chamber on a fully open
edge a time constant of about 0.12 ms at its dead volume (0.7 ms at mid-stroke), below what an
explicit step of 0.25 ms survives; and the spool's 2 ms lag and the pneumatic spring (about
10 Hz at mid-stroke, faster toward the ends, lightly damped) want sub-steps well under a millisecond to be followed to a
fraction of a millimetre (the error falls linearly with the sub-step: 0.77 / 0.38 / 0.15 mm
of a 130 mm move at 0.5 / 0.25 / 0.1 ms, against solve_ivp). In each sub-step:

1. the spool follows its first-order lag exactly (the command held over the step);
2. each chamber's pressure takes one linearly implicit (Rosenbrock-Euler) step,
   ``p+ = p + h f(p) / (1 - h df/dp)``, with f the chamber equation and df/dp its exact
   derivative in the chamber's own pressure: stable for any stiffness, and exact at the
   balance pressures, so a still chamber does not ring;
3. the velocity takes a semi-implicit step with the new pressures: the viscous term implicit,
   the Stribeck friction at the present speed, and Karnopp's stiction (the piston stays at rest,
   or stops within the step, while the force that would hold it is within Fs);
4. the position follows the new velocity (symplectic Euler, which neither damps nor excites the
   pneumatic spring's oscillation while omega h << 2); the end stops are inelastic (position
   clamped at 0 and the stroke, the velocity into the stop zeroed: the cushioning takes the impact).

tests/test_axis_model.py checks the result against scipy's ``solve_ivp`` on the continuous
model. A step costs about 10 us in pure-Python floats (docs/simulator.md gives the figure), so
the plant thread runs it at 1 kHz without numba.
"""
from __future__ import annotations

import math

from hal.linear_axis import R_AIR, AxisParams, AxisState, flow_into, spool_of
from hal.linear_axis_facts import rest_state

MAX_SUBSTEP_S = 0.25e-3  # the longest integration step [s] (module docstring: why)


class AxisModel:
    """One axis's state and its fixed-step integration. State: ``position_m`` [m] from the
    retracted end, ``velocity_m_s`` [m/s], ``p_head_pa``, ``p_rod_pa`` [Pa abs], ``spool``
    (-1..1); ``external_force_n`` [N] along +x is a disturbance the caller may set."""

    def __init__(self, params: AxisParams, dt: float = 1e-3, state: AxisState | None = None):
        if not (math.isfinite(dt) and 0.0 < dt <= 0.1):
            raise ValueError(f"dt {dt} s: must be within (0, 0.1] s")
        self.params = params
        self.dt = dt
        self.substeps = max(1, math.ceil(dt / MAX_SUBSTEP_S - 1e-9))
        h = dt / self.substeps
        p = params
        s_l = p.underlap
        # edge area / sqrt(T) = k_area (s + sqrt(s^2 + s_L^2)) [hal.linear_axis.edge_area]
        k_area = p.orifice_area_m2 / (1.0 + math.sqrt(1.0 + s_l * s_l)) / math.sqrt(p.temperature_k)
        self._const = (h, math.exp(-h / p.valve_time_constant_s), k_area, s_l * s_l, p.supply_pa, p.atmosphere_pa,
                       p.polytropic, R_AIR * p.temperature_k, p.area_head, p.area_rod,
                       p.atmosphere_pa * p.area_rod_section, p.dead_volume_head_m3, p.dead_volume_rod_m3, p.stroke_m,
                       h / p.moving_mass_kg, p.viscous_n_s_m, p.coulomb_n, p.static_n - p.coulomb_n,
                       p.static_n, 1.0 / p.stribeck_velocity_m_s, p.load_force_n)
        self.external_force_n = 0.0
        self.reset(state if state is not None else self.rest_state())

    @property
    def supply_pa(self) -> float:
        """The supply's absolute pressure [Pa] (the simulator's loss of supply sets it to the atmosphere's)."""
        return self._const[4]

    @supply_pa.setter
    def supply_pa(self, value: float) -> None:
        const = list(self._const)
        const[4] = value
        self._const = tuple(const)

    def rest_state(self, position_m: float | None = None) -> AxisState:
        """At rest at a position [m] (default mid-stroke), the valve at its null
        (:func:`hal.linear_axis_facts.rest_state`)."""
        return rest_state(self.params, position_m)

    def reset(self, state: AxisState) -> None:
        """Put the axis in a state (positions beyond the stroke are clamped to it)."""
        self.position_m = min(max(state.position_m, 0.0), self.params.stroke_m)
        self.velocity_m_s = state.velocity_m_s
        self.p_head_pa, self.p_rod_pa = state.p_head_pa, state.p_rod_pa
        self.spool = state.spool

    def state(self) -> AxisState:
        return AxisState(self.position_m, self.velocity_m_s, self.p_head_pa, self.p_rod_pa, self.spool)

    def step(self, volts: float) -> None:
        """Advance one step ``dt`` with the valve commanded to ``volts`` (held over the step; the
        valve's 0-10 V range clamps it). A non-finite command is a ValueError: nothing moves."""
        if not math.isfinite(volts):
            raise ValueError(f"valve command {volts} V: not a number")
        (h, decay, k_area, sl2, ps, pa, n, rt, ah, ar, pa_ar, v0h, v0r, stroke, hm, visc, fc, drop, fs, inv_vs,
         load) = self._const
        target = spool_of(volts)
        force_fixed = load + self.external_force_n - pa_ar
        x, v, p1, p2, s = self.position_m, self.velocity_m_s, self.p_head_pa, self.p_rod_pa, self.spool
        flow = flow_into
        for _ in range(self.substeps):
            s = target + (s - target) * decay
            root = math.sqrt(s * s + sl2)
            g_pos, g_neg = k_area * (root + s), k_area * (root - s)  # supply->head & rod->exhaust; the others
            # chambers: p' = n/V (R T m_dot - p V'), one linearly implicit step each
            m_a, d_a = flow(g_pos, ps, p1)
            m_b, d_b = flow(g_neg, pa, p1)
            vol = v0h + ah * x
            f = n / vol * (rt * (m_a + m_b) - p1 * ah * v)
            jac = n / vol * (rt * (d_a + d_b) - ah * v)
            p1 += h * f / max(1.0 - h * jac, 0.5)
            m_a, d_a = flow(g_neg, ps, p2)
            m_b, d_b = flow(g_pos, pa, p2)
            vol = v0r + ar * (stroke - x)
            f = n / vol * (rt * (m_a + m_b) + p2 * ar * v)
            jac = n / vol * (rt * (d_a + d_b) + ar * v)
            p2 += h * f / max(1.0 - h * jac, 0.5)
            # piston: M v' = A_h p_h - A_rod p_r - p_atm A_r + F_load - beta v - F_f(v)
            force = ah * p1 - ar * p2 + force_fixed
            slipping = False
            if v != 0.0:
                u = v * inv_vs
                sign = 1.0 if v > 0.0 else -1.0
                v_try = (v + hm * (force - sign * (fc + drop * math.exp(-u * u)))) / (1.0 + hm * visc)
                if v_try * sign > 0.0:
                    v, slipping = v_try, True
            if not slipping:  # at rest, or this step would stop or reverse it: does stiction hold it?
                hold = v / hm + force
                if -fs <= hold <= fs:
                    v = 0.0
                else:
                    v = (v + hm * (force - (fs if hold > 0.0 else -fs))) / (1.0 + hm * visc)
            x += h * v
            if x <= 0.0:
                x = 0.0
                if v < 0.0:
                    v = 0.0
            elif x >= stroke:
                x = stroke
                if v > 0.0:
                    v = 0.0
        self.position_m, self.velocity_m_s, self.p_head_pa, self.p_rod_pa, self.spool = x, v, p1, p2, s
