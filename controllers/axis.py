"""Controllers of the linear pneumatic axis (rig-facts §5): a double-acting cylinder on a 5/3
proportional valve. SI inside (position m, velocity m/s, pressure Pa gauge, force N), the
valve's command out, in volts about its centre (:mod:`hal.actuation`, ``valve``).

``axis_pid``: PID on the position error with the derivative on the measured velocity and a
velocity feed-forward,

    u = Kp e + Kd (v_r - v) + Kff v_r + I,    I' = (Kp / Ti) e + (u_sat - u) / Tt,    e = r - x,

the integral bled back while the valve is saturated (back-calculation, Åström & Hägglund);
it starts from the command in force, so taking over is bumpless. Kp [V/m], Kd and Kff
[V s/m]. The gains suit one axis (its valve's flow, its mass): a rig file gives its own
(``[controllers.axis_pid]``, docs/rigs.md) over the class's modest defaults; ``sim-axis``'s
are tuned on its simulated plant (docs/controllers.md, "The linear axis").

``axis_pva``, the model-based one: position, velocity and acceleration state feedback (PVA;
Ning & Bone, "High steady-state accuracy pneumatic servo positioning system with PVA/PV control
and friction compensation", IEEE ICRA 2002) whose gains are placed on the axis's own model.
The valve-controlled cylinder linearised about mid-stroke (:func:`hal.linear_axis_facts.linearise`;
Merritt, *Hydraulic Control Systems*, 1967) is the third-order

    x''' + 2 zeta wn x'' + wn^2 x' = g u,    g = K_v wn^2   [m/(s^3 V)]

and the law, on the errors to the reference (r, v_r, a_r),

    u = kp (r - x) + kv (v_r - v) + ka (a_r - a) + (wn^2 v_r + 2 zeta wn a_r) / g + I,   I' = (kp / Ti) e

puts the error's poles at s = -p (``pole_ratio`` x wc) and the pair wc (``bandwidth_hz``),
``damping``: matching s^3 + (2 zeta wn + g ka) s^2 + (wn^2 + g kv) s + g kp with
(s + p)(s^2 + 2 zc wc s + wc^2) gives

    ka = (p + 2 zc wc - 2 zeta wn) / g,   kv = (wc^2 + 2 zc wc p - wn^2) / g,   kp = p wc^2 / g.

The acceleration is not differentiated twice from the position: it is the model's, from the
measured chamber pressures (R&H's equation of motion, Richer & Hurmuzlu, ASME JDSMC 122(3),
2000, Part I; gauge pressures, so the atmosphere on the rod's section drops out) and the
model's friction (:func:`hal.linear_axis.friction_magnitude`, Karnopp's stiction at rest),

    F = p_h A_h - p_r A_rod - beta v + F_load
    a = (F - F_f(|v|) sgn v) / M            |v| >= ``REST_M_S``
    a = (F - clip(F, -Fs, Fs)) / M          at rest: stiction holds up to Fs,

low-passed at ``accel_hz``. The integral (conditional: never further into a saturated valve)
takes up the valve's null offset and what the model's friction misses. ``kp``, ``kv``, ``ka`` are published.
"""
from __future__ import annotations

import math

from controllers.base import Controller, JointState, ParamError, ParamSpec, Reference, SignalSpec, clamp
from hal.linear_axis import AxisParams, friction_magnitude
from hal.linear_axis_facts import linearise

REST_M_S = 0.002  # below this speed [m/s] the piston is taken to be at rest (Karnopp's band)


class AxisController(Controller):
    """What both axis controllers share: one valve command per joint, each joint's AxisParams."""

    actuation = "valve"

    def __init__(self, context, **values):
        self._check_actuation(context)
        self.axes = [a if a is not None else AxisParams() for a in (context.axes or [None] * context.n)]
        if context.width != context.n:
            raise ParamError(f"{self.name}: expected one valve command per joint, got {context.width} commands")
        self._i = [0.0] * context.n  # integral part [V]
        self._u = [0.0] * context.n  # the last output [V]
        self._x = [0.0] * context.n  # filtered position [m]
        self._taking_over = False
        super().__init__(context, **values)

    def reset(self, state: JointState, last_output) -> None:
        """Bumpless: the integral carries the command in force; the filters start where the axis is."""
        self._i = [float(u) for u in last_output]
        self._u = list(self._i)
        self._x = [float(x) for x in state.angles]
        self._taking_over = True


class AxisPID(AxisController):
    """PID on the axis's position [m] to the valve [V], derivative on the measured velocity."""

    name = "axis_pid"
    params = (
        ParamSpec("Kp", "V/m", 0.0, 1.0e5, (100.0,), "proportional gain"),
        ParamSpec("Ti", "s", 0.0, 1.0e4, (1.0,), "integral time; 0 turns integral action off"),
        ParamSpec("Kd", "V s/m", 0.0, 1.0e3, (10.0,), "gain on the velocity error v_r - v"),
        ParamSpec("Kff", "V s/m", 0.0, 1.0e3, (0.0,), "velocity feed-forward on v_r (about 1 / K_v)"),
        ParamSpec("Tt", "s", 1e-3, 1.0e4, (0.1,), "anti-windup tracking time"),
        ParamSpec("filter_hz", "Hz", 0.0, 500.0, (100.0,), "first-order low-pass on the position (0: none)"),
    )
    internals = (SignalSpec("p", "V", "proportional part Kp e"), SignalSpec("i", "V", "integral part"),
                 SignalSpec("d", "V", "velocity part"))

    def __init__(self, context, **values):
        self._parts = [[0.0] * context.n for _ in range(3)]
        super().__init__(context, **values)

    def derive(self, values):
        """Per joint: (Kp h / Ti, h / Tt, the position filter's update gain)."""
        h = self.context.dt
        return tuple((k * h / t if t > 0 else 0.0, h / tt, 1.0 - math.exp(-2 * math.pi * f * h) if f > 0 else 1.0)
                     for k, t, tt, f in zip(values["Kp"], values["Ti"], values["Tt"], values["filter_hz"]))

    def step(self, state: JointState, reference: Reference) -> list[float]:
        kp, kd, kff = self.p("Kp"), self.p("Kd"), self.p("Kff")
        out = self._u
        for j, (ki, kt, a) in enumerate(self.k):
            x = self._x[j] = self._x[j] + a * (state.angles[j] - self._x[j])
            e = reference.angles[j] - x
            v_r = reference.velocities[j]
            if self._taking_over:  # bumpless: the output in force, whatever the error
                self._i[j] -= kp[j] * e + kd[j] * (v_r - state.velocities[j]) + kff[j] * v_r
            p, d = kp[j] * e, kd[j] * (v_r - state.velocities[j]) + kff[j] * v_r
            v = p + d + self._i[j]
            u = clamp(v, self.u_lo[j], self.u_hi[j])
            self._parts[0][j], self._parts[1][j], self._parts[2][j] = p, self._i[j], d
            self._i[j] += ki * e + kt * (u - v)
            out[j] = u
        self._taking_over = False
        return list(out)

    def internal_signals(self) -> list[list[float]]:
        return [list(p) for p in self._parts]


class AxisPVA(AxisController):
    """Position-velocity-acceleration state feedback placed on the axis's third-order model."""

    name = "axis_pva"
    params = (
        ParamSpec("bandwidth_hz", "Hz", 0.1, 50.0, (8.0,), "wc: the error's complex pole pair"),
        ParamSpec("damping", "-", 0.1, 2.0, (0.9,), "zc: that pair's damping ratio"),
        ParamSpec("pole_ratio", "-", 0.1, 20.0, (1.0,), "the real pole at this times wc"),
        ParamSpec("Ti", "s", 0.0, 1.0e4, (0.5,), "integral time; 0 turns integral action off"),
        ParamSpec("accel_hz", "Hz", 1.0, 500.0, (50.0,), "low-pass on the model's acceleration"),
        ParamSpec("filter_hz", "Hz", 0.0, 500.0, (100.0,), "first-order low-pass on the position (0: none)"),
    )
    internals = (SignalSpec("kp", "V/m", "position gain"), SignalSpec("kv", "V s/m", "velocity gain"),
                 SignalSpec("ka", "V s^2/m", "acceleration gain"), SignalSpec("a", "m/s^2", "model acceleration"),
                 SignalSpec("i", "V", "integral part"))

    def __init__(self, context, **values):
        self._a = [0.0] * context.n  # filtered model acceleration [m/s^2]
        super().__init__(context, **values)

    def derive(self, values):
        """Per joint from its model at mid-stroke: (kp, kv, ka, feed-forward per v_r and a_r,
        kp h / Ti, the acceleration and position filters' update gains); module docstring."""
        h, gains = self.context.dt, []
        for j, axis in enumerate(self.axes):
            lin = linearise(axis)
            wn, zeta = lin.natural_frequency_rad_s, lin.damping_ratio
            g = lin.velocity_gain_m_s_v * wn * wn
            wc = 2 * math.pi * values["bandwidth_hz"][j]
            zc, p = values["damping"][j], values["pole_ratio"][j] * wc
            kp = p * wc * wc / g  # [V/m]
            kv = (wc * wc + 2 * zc * wc * p - wn * wn) / g  # [V s/m]
            ka = (p + 2 * zc * wc - 2 * zeta * wn) / g  # [V s^2/m]
            ti, fa, fx = values["Ti"][j], values["accel_hz"][j], values["filter_hz"][j]
            gains.append((kp, kv, ka, wn * wn / g, 2 * zeta * wn / g, kp * h / ti if ti > 0 else 0.0,
                          1.0 - math.exp(-2 * math.pi * fa * h), 1.0 - math.exp(-2 * math.pi * fx * h) if fx else 1.0))
        return tuple(gains)

    def step(self, state: JointState, reference: Reference) -> list[float]:
        out, pressures = self._u, state.pressures
        for j, (kp, kv, ka, fv, fa, ki, a_gain, x_gain) in enumerate(self.k):
            axis = self.axes[j]
            x = self._x[j] = self._x[j] + x_gain * (state.angles[j] - self._x[j])
            v = state.velocities[j]
            p_h, p_r = (pressures[2 * j], pressures[2 * j + 1]) if len(pressures) > 2 * j + 1 else (math.nan, math.nan)
            if p_h == p_h and p_r == p_r:  # both transmitters read (NaN: none, or implausible): else the last estimate
                force = p_h * axis.area_head - p_r * axis.area_rod - axis.viscous_n_s_m * v + axis.load_force_n
                if -REST_M_S < v < REST_M_S:
                    force -= clamp(force, -axis.static_n, axis.static_n)
                else:
                    force -= math.copysign(friction_magnitude(axis, abs(v)), v)
                self._a[j] += a_gain * (force / axis.moving_mass_kg - self._a[j])
            r, v_r, a_r = reference.angles[j], reference.velocities[j], reference.accelerations[j]
            e = r - x
            fb = kp * e + kv * (v_r - v) + ka * (a_r - self._a[j]) + fv * v_r + fa * a_r
            if self._taking_over:
                self._i[j] -= fb
            w = fb + self._i[j]
            u = clamp(w, self.u_lo[j], self.u_hi[j])
            if ki and (u == w or (e > 0) != (u >= self.u_hi[j])):  # never further into a saturated valve
                self._i[j] += ki * e
            out[j] = u
        self._taking_over = False
        return list(out)

    def internal_signals(self) -> list[list[float]]:
        return [[g[0] for g in self.k], [g[1] for g in self.k], [g[2] for g in self.k], list(self._a), list(self._i)]
