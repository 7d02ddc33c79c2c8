"""A lab's own controller for pneumad: PD + integral + the nominal model's feed-forward.

Per joint, with e = r - th [rad], the reference r, r', r'' [rad, rad/s, rad/s^2] and the loop
period h [s], the output V_MV [V] is

    u = f V_ff(r, r', r'') + Kp e + Kd (r' - th') + i,    i <- i + (Kp h / Ti) e

V_ff is the V_MV that holds the reference's motion in steady state on the nominal model
(rig-facts §1 [2-43]: J r'' + D r' + K (r - th_0) + Fc sgn r' - tau_bias = kt V_ff;
``NominalJoint.static_volts``), f its share (``feedforward``). Kp comes from the model, off the
loop: the joints are so damped (D/J of 331 and 1440 1/s) that below a few hertz each is an
integrator, th' = (kt/D) V, so a crossover at f_c takes Kp = 2 pi f_c D / kt [V/rad].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from controllers.base import Controller, ParamSpec, SignalSpec, clamp


@dataclass(frozen=True)
class Design:
    """What a parameter set comes to, per joint: derived off the loop."""

    kp: tuple[float, ...]  # [V/rad]
    ki: tuple[float, ...]  # Kp h / Ti [V/(rad cycle)]
    kd: tuple[float, ...]  # [V s/rad]
    ff: tuple[float, ...]  # the feed-forward's share


class PDFF(Controller):
    """PD + integral + the nominal model's feed-forward, Kp from a crossover frequency."""

    name = "mylab_pdff"
    params = (
        ParamSpec("crossover_hz", "Hz", 0.05, 3.0, (0.5, 0.5), "the loop's crossover: Kp = 2 pi f D / kt"),
        ParamSpec("Ti", "s", 0.0, 100.0, (1.3, 1.3), "integral time; 0: no integral action"),
        ParamSpec("Kd", "V s/rad", 0.0, 50.0, (0.0, 0.0), "gain on the velocity error"),
        ParamSpec("feedforward", "-", 0.0, 1.0, (1.0, 1.0), "share of the model's V_MV fed forward"),
    )
    internals = (SignalSpec("ff", "V", "the model's feed-forward"), SignalSpec("i", "V", "the integral part"))

    def __init__(self, context, **values):
        n = context.n
        self._i = [0.0] * n  # the integral part [V]
        self._ff = [0.0] * n  # this cycle's feed-forward [V]
        self._last = [0.0] * n  # the output in force when it took over [V]
        self._taking_over = False
        super().__init__(context, **values)  # validates the parameters and derives them

    def derive(self, values) -> Design:
        """Off the loop, at build and at each parameter change: a joint with no model is refused."""
        models = self.context.require_models(self.name)
        h = self.context.dt
        kp = tuple(2.0 * math.pi * f * m.D / m.kt for f, m in zip(values["crossover_hz"], models))
        return Design(kp, tuple(k * h / t if t > 0 else 0.0 for k, t in zip(kp, values["Ti"])),
                      values["Kd"], values["feedforward"])

    def reset(self, state, last_output):
        """Bumpless: the first step puts into the integral what makes its output this one."""
        self._last = list(last_output)
        self._taking_over = True

    def step(self, state, reference):
        k, models = self.k, self.context.models
        out = []
        for j in range(self.context.n):
            r, rv = reference.angles[j], reference.velocities[j]
            e = r - state.angles[j]
            ff = self._ff[j] = k.ff[j] * models[j].static_volts(r, rv, reference.accelerations[j])
            pd = k.kp[j] * e + k.kd[j] * (rv - state.velocities[j])
            if self._taking_over:
                self._i[j] = self._last[j] - ff - pd
            v = ff + pd + self._i[j]
            u = clamp(v, self.u_lo[j], self.u_hi[j])
            if u == v or (v > u) != (e > 0):  # anti-windup: no integration deeper into a limit
                self._i[j] += k.ki[j] * e
            out.append(u)
        self._taking_over = False
        return out

    def internal_signals(self):
        return [list(self._ff), list(self._i)]
