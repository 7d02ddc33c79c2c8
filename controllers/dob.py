"""Disturbance observer (rig-facts §1 "Disturbance observer"), composable with SMC and LTI.

The plant is taken as th = P_n (u + u_off + d) with the delay-free nominal model of [2-43]

    P_n(s) = kt / ((J s^2 + D s + K)(T_ep s + 1))  [rad/V]   followed by exp(-T_dly s),

and d [V] the equivalent input disturbance (friction, load, model error). Through the nominal
inverse and a low-pass Q(s) = 1/(tau s + 1)^3, which makes Q P_n^-1 proper [Ohnishi 1987]:

    d_hat = Q P_n^-1 th  -  Q u(t - T_dly)  -  u_off,      u = u_inner - d_hat.

The estimate lags by T_dly (it cannot see sooner); tau sets the Q filter's bandwidth and with
it the trade between rejection and noise. Both filters are discretised by Tustin's method
(scipy.signal.cont2discrete) at the loop period. Q P_n^-1 has relative degree 0, so the
sensor's white noise passes it at full high-frequency gain: the estimate then goes through a
fourth pole of Q, a first-order low-pass at ``dob_filter_hz`` (20 Hz; our addition,
:mod:`controllers.smoothing`), which halves smc_dob's output motion at rest (19 / 35 V/s
to 10 / 15 V/s, bottom / middle). Units: rad in, V out.
"""
from __future__ import annotations

import numpy as np

from controllers.base import Controller, JointState, ParamSpec, Reference, SignalSpec
from controllers.nominal import NominalJoint
from controllers.smoothing import smoothing_gains, smoothing_param

D_HAT = SignalSpec("d_hat", "V", "the observer's input-disturbance estimate, subtracted from the output")
DOB_PARAMS = (
    ParamSpec("dob_tau", "s", 1e-3, 10.0, (0.12, 0.12),
              "Q filter time constant: 1/(tau s + 1)^3 (bottom 0.12 s: at 0.05 s the loop oscillated on a plant "
              "with 1.41x the gain and 1.2x the dead time; middle 0.12 s, designed for the worst corner of the "
              "thesis's ranges, issue 32: at 0.05 or 0.08 s SMC+DOB tripped while holding on a plant with 1.41x "
              "the gain and half the damping)"),
    ParamSpec("dob_limit", "V", 0.0, 10.0, (3.0, 2.0),
              "largest correction the observer may apply (middle 2 V: with its slower Q filter, at 3 V SMC+DOB "
              "swung limit to limit after an output pinned by a push was released, tests/test_saturation.py)"),
    smoothing_param("dob_filter_hz", "the estimate: a fourth pole of Q"),
)


class _ObserverFilter:
    """Q P_n^-1 th - Q u for one joint as one third-order filter: after Tustin's map both terms
    share Q's denominator, so a single direct form II transposed update (three states, no
    loops) computes their difference. Written out for the cost goal of a step (<= 20 us)."""

    __slots__ = ("coef", "z0", "z1", "z2")

    def __init__(self, num_th, num_u, den):
        if len(den) != 4 or len(num_th) != 4 or len(num_u) != 4:
            raise ValueError("the observer filter is third order (Q = 1/(tau s + 1)^3)")
        a0 = float(den[0])
        b, c, a = ([float(v) / a0 for v in x] for x in (num_th, num_u, den))  # plain floats: numpy scalars are slow
        self.coef = (b[0], b[1], b[2], b[3], -c[0], -c[1], -c[2], -c[3], a[1], a[2], a[3])
        self.z0 = self.z1 = self.z2 = 0.0

    def settle(self, th: float, u: float) -> float:
        """Start at the steady state for constant inputs; that state's output."""
        b0, b1, b2, b3, c0, c1, c2, c3, a1, a2, a3 = self.coef
        y = ((b0 + b1 + b2 + b3) * th + (c0 + c1 + c2 + c3) * u) / (1.0 + a1 + a2 + a3)
        self.z2 = b3 * th + c3 * u - a3 * y
        self.z1 = b2 * th + c2 * u - a2 * y + self.z2
        self.z0 = b1 * th + c1 * u - a1 * y + self.z1
        return y

    def __call__(self, th: float, u: float) -> float:
        b0, b1, b2, b3, c0, c1, c2, c3, a1, a2, a3 = self.coef
        y = b0 * th + c0 * u + self.z0
        self.z0 = b1 * th + c1 * u - a1 * y + self.z1
        self.z1 = b2 * th + c2 * u - a2 * y + self.z2
        self.z2 = b3 * th + c3 * u - a3 * y
        return y


class DisturbanceObserver:
    """d_hat per joint from measured angles and the inner controller's outputs."""

    def __init__(self, models: tuple[NominalJoint, ...], dt: float, tau: tuple[float, ...], limit: tuple[float, ...],
                 filter_hz: tuple[float, ...] = (0.0,)):
        self.n = len(models)
        self._smooth = smoothing_gains(filter_hz if len(filter_hz) == self.n else filter_hz * self.n, dt)
        self._raw = [0.0] * self.n  # the estimate before the fourth pole [V]
        self.limit = limit
        self.models = models
        self.delay = [m.delay_steps(dt) for m in models]
        self.u_off = [m.input_offset for m in models]
        from scipy.signal import cont2discrete  # here, off the loop: at module level it cost
        # the loop's process 1-2 s of every daemon start
        self._filters = []
        for m, t in zip(models, tau):
            plant_den = [m.J * m.T_ep, m.J + m.D * m.T_ep, m.D + m.K * m.T_ep, m.K]  # (J s^2 + D s + K)(T_ep s + 1)
            q_den = [t ** 3, 3 * t ** 2, 3 * t, 1.0]
            num_i, den, _ = cont2discrete(([v / m.kt for v in plant_den], q_den), dt, method="bilinear")
            num_q, den_q, _ = cont2discrete(([1.0], q_den), dt, method="bilinear")
            if not np.allclose(den_q, den, rtol=1e-9, atol=0.0):
                raise ValueError("the Q filter and the nominal inverse do not share a denominator")
            self._filters.append(_ObserverFilter(list(num_i.ravel()), list(num_q.ravel()), list(den)))
        self._buf = [[0.0] * (d + 1) for d in self.delay]
        self._joints = tuple(zip(self._filters, self._buf, self.u_off, limit, self._smooth))  # what estimate() walks
        self._k = 0
        self.d_hat = [0.0] * self.n

    def reset(self, angles, last_output) -> None:
        """Filters at steady state for these angles and this output, as if at rest."""
        for j in range(self.n):
            self._buf[j][:] = [float(last_output[j])] * (self.delay[j] + 1)
            self._raw[j] = self._filters[j].settle(angles[j], last_output[j]) - self.u_off[j]
        self._k = 0

    def estimate(self, angles) -> list[float]:
        """d_hat per joint [V] from this cycle's angles (kept in ``d_hat``)."""
        self._k = k = self._k + 1
        d_hat = self.d_hat
        raw = self._raw
        for j, (f, buf, off, lim, a) in enumerate(self._joints):
            d = f(angles[j], buf[k % len(buf)]) - off  # buf[k]: written N + 1 cycles ago, the input th now shows
            d = raw[j] = raw[j] + a * (d - raw[j])  # Q's fourth pole
            d_hat[j] = -lim if d < -lim else lim if d > lim else d
        return d_hat

    def sent(self, applied) -> None:
        """Remember what was applied this cycle (the delayed input of later cycles)."""
        k = self._k
        for buf, u in zip(self._buf, applied):
            buf[k % len(buf)] = u


class WithDisturbanceObserver(Controller):
    """A controller with the disturbance observer around it: u = u_inner - d_hat.
    Subclasses name the inner controller class; its parameters come first, then dob_*.

    Anti-windup: each cycle the inner controller's output range is the rig's moved by d_hat,
    so it clamps (and stops its integrators) exactly when the plant's input is at a limit."""

    inner_class: type[Controller]

    def __init__(self, context, **values):
        self.models = context.require_models(self.name)
        self._taking_over: list[float] | None = None
        own = {p.name for p in DOB_PARAMS}
        self.inner = self.inner_class(context, **{k: v for k, v in values.items() if k not in own})
        super().__init__(context, **values)

    def derive(self, values):
        inner_names = {p.name for p in self.inner_class.params}
        inner = self.inner.prepare_params({k: v for k, v in values.items() if k in inner_names})
        return inner, DisturbanceObserver(self.models, self.context.dt, values["dob_tau"], values["dob_limit"],
                                          values["dob_filter_hz"])

    def apply_params(self, prepared) -> None:
        values, (inner, observer) = prepared
        old = getattr(self, "k", None)
        self._values, self.k = values, observer
        self.inner.apply_params(inner)
        if old is not None:  # a live change: the new observer takes over from the old one's view
            observer.reset(self._last_angles, self._last_output)
            observer.d_hat = list(old.d_hat)

    def reset(self, state: JointState, last_output) -> None:
        self.k.reset(state.angles, last_output)
        self._last_angles, self._last_output = list(state.angles), list(last_output)
        self._taking_over = list(last_output)

    def step(self, state: JointState, reference: Reference) -> list[float]:
        d_hat = self.k.estimate(state.angles)
        if self._taking_over is not None:
            # bumpless: the inner controller takes over the output plus the correction it now meets
            self.inner.reset(state, [u + d for u, d in zip(self._taking_over, d_hat)])
            self._taking_over = None
        inner_lo, inner_hi = self.inner.u_lo, self.inner.u_hi
        for j, d in enumerate(d_hat):  # the inner controller's range is the rig's moved by d_hat: its
            inner_lo[j] = self.u_lo[j] + d  # anti-windup then sees the saturation the plant sees
            inner_hi[j] = self.u_hi[j] + d
        out = []
        for v, d, lo, hi in zip(self.inner.step(state, reference), d_hat, self.u_lo, self.u_hi):
            v -= d
            out.append(lo if v < lo else hi if v > hi else v)
        self.k.sent(out)
        self._last_angles, self._last_output = state.angles, out  # read only by a live change, at a boundary
        return out

    def internal_signals(self) -> list[list[float]]:
        return [*self.inner.internal_signals(), list(self.k.d_hat)]

    def applied(self, output) -> None:
        self.k.sent(output)
        self._last_output = list(output)
        self.inner.applied([u + d for u, d in zip(output, self.k.d_hat)])
