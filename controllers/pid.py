"""PID with a filtered derivative and back-calculation anti-windup (rig-facts §1, [3-3, 3-4]).

    C(s) = Kp (1 + 1/(Ti s) + Td s / ((Td/N) s + 1))

Error e = r - th in rad, output V_MV in V, so Kp is in V/rad: the thesis's gains (in V/deg)
times 180/pi. Discretised at the loop period h: integral by forward Euler, derivative by
backward difference of the filtered form (Åström & Hägglund). When the output saturates,
the integral is bled back at the rate (u_sat - u)/Tt so it cannot wind up.

The measured angle passes a first-order low-pass (``filter_hz``, 20 Hz; our addition, see
:mod:`controllers.smoothing`): the thesis's Kp of 46-50 V/rad turned the rig's 0.03 deg of
sensor noise into 35 V/s of output motion at rest.

The thesis gives no anti-windup; Tt = 0.2 s is our choice. With it the bottom joint's 10 deg
step (which saturates V_MV at +6 V) gives about 6 % overshoot and settles in about 2 s,
the thesis's own figures; with Tt = Ti the same step overshoots about 18 %.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from controllers.base import Controller, JointState, ParamSpec, Reference, SignalSpec, clamp
from controllers.smoothing import smoothing_gains, smoothing_param

DEG = 180.0 / math.pi


@dataclass(frozen=True)
class _Gains:
    """Discrete gains per joint at the loop period."""

    kp: tuple[float, ...]  # [V/rad]
    ki: list[float]  # Kp h / Ti [V/(rad cycle)]
    ad: list[float]  # derivative filter pole
    bd: list[float]  # derivative gain [V/rad]
    kt: list[float]  # h / Tt
    smooth: tuple[float, ...]  # the angle filter's update gain


class PID(Controller):
    """PID per joint, thesis gains by default (bottom Kp 0.81 V/deg, Ti 1.3 s; middle 0.88, 2.0 s)."""

    name = "pid"
    params = (
        ParamSpec("Kp", "V/rad", 0.0, 1.0e4, (0.81 * DEG, 0.88 * DEG), "proportional gain"),
        ParamSpec("Ti", "s", 0.0, 1.0e6, (1.30, 2.0), "integral time; 0 turns integral action off"),
        ParamSpec("Td", "s", 0.0, 100.0, (0.0, 0.0), "derivative time"),
        ParamSpec("N", "-", 1.0, 1000.0, (200.0, 200.0), "derivative filter: the pole sits at N/Td"),
        ParamSpec("Tt", "s", 1e-3, 1.0e4, (0.2, 0.2), "anti-windup tracking time"),
        smoothing_param("filter_hz", "the measured angle"),
    )

    internals = (SignalSpec("p", "V", "proportional part Kp e"), SignalSpec("i", "V", "integral part"),
                 SignalSpec("d", "V", "filtered derivative part"))

    def __init__(self, context, **values):
        self._i = [0.0] * context.n  # integral part [V]
        self._i_used = [0.0] * context.n  # ... as it was in the last output [V]
        self._d = [0.0] * context.n  # filtered derivative part [V]
        self._e_prev = [0.0] * context.n  # last error [rad]
        self._q = [0.0] * context.n  # filtered angle [rad]
        self._taking_over = False
        super().__init__(context, **values)

    def derive(self, values) -> _Gains:
        h = self.context.dt
        kp, ti, td, n = values["Kp"], values["Ti"], values["Td"], values["N"]
        return _Gains(kp=kp, ki=[k * h / t if t > 0 else 0.0 for k, t in zip(kp, ti)],
                      ad=[t / (t + nn * h) for t, nn in zip(td, n)],
                      bd=[k * t * nn / (t + nn * h) for k, t, nn in zip(kp, td, n)],
                      kt=[h / tt for tt in values["Tt"]], smooth=smoothing_gains(values["filter_hz"], h))

    def reset(self, state: JointState, last_output) -> None:
        """Take over bumplessly: the integral carries the output in force."""
        self._d = [0.0] * self.context.n
        self._e_prev = [0.0] * self.context.n
        self._i = list(last_output)
        self._q = [float(q) for q in state.angles]
        self._taking_over = True

    def step(self, state: JointState, reference: Reference) -> list[float]:
        out = []
        g = self.k
        kp = g.kp
        first = self._taking_over
        for j in range(self.context.n):
            q = self._q[j] = self._q[j] + g.smooth[j] * (state.angles[j] - self._q[j])
            e = reference.angles[j] - q
            if first:  # bumpless: the P part at the switch goes into the integral's account
                self._i[j] -= kp[j] * e
                self._e_prev[j] = e
            self._d[j] = g.ad[j] * self._d[j] + g.bd[j] * (e - self._e_prev[j])
            self._i_used[j] = self._i[j]  # the integral part of this output (published)
            v = kp[j] * e + self._i[j] + self._d[j]
            u = clamp(v, self.u_lo[j], self.u_hi[j])
            self._i[j] += g.ki[j] * e + g.kt[j] * (u - v)
            self._e_prev[j] = e
            out.append(u)
        self._taking_over = False
        return out

    def internal_signals(self) -> list[list[float]]:
        return [[k * e for k, e in zip(self.k.kp, self._e_prev)], list(self._i_used), list(self._d)]
