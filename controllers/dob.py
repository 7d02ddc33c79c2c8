"""Disturbance observer (rig-facts §1 "Disturbance observer"), composable with SMC and LTI.

The plant is taken as th = P_n (u + u_off + d) with the delay-free nominal model of [2-43]

    P_n(s) = kt / ((J s^2 + D s + K)(T_ep s + 1))  [rad/V]   followed by exp(-T_dly s),

and d [V] the equivalent input disturbance (friction, load, model error). Through the nominal
inverse and a low-pass Q(s) = 1/(tau s + 1)^3, which makes Q P_n^-1 proper [Ohnishi 1987]:

    d_hat = Q P_n^-1 th  -  Q u(t - T_dly)  -  u_off,      u = u_inner - d_hat.

The estimate lags by T_dly (it cannot see sooner); tau sets the Q filter's bandwidth and with
it the trade between rejection and noise. Both filters are discretised by Tustin's method
(scipy.signal.cont2discrete) at the loop period. Units: rad in, V out.
"""
from __future__ import annotations

from scipy.signal import cont2discrete

from controllers.base import Controller, JointState, ParamSpec, Reference, clamp
from controllers.nominal import NominalJoint

DOB_PARAMS = (
    ParamSpec("dob_tau", "s", 1e-3, 10.0, (0.05, 0.05), "Q filter time constant: 1/(tau s + 1)^3"),
    ParamSpec("dob_limit", "V", 0.0, 10.0, (3.0, 3.0), "largest correction the observer may apply"),
)


class _Filter:
    """A discrete SISO transfer function, direct form II transposed."""

    def __init__(self, num, den):
        a0 = den[0]
        self.b = [v / a0 for v in num]
        self.a = [v / a0 for v in den]
        self.z = [0.0] * (len(self.a) - 1)

    def settle(self, x: float) -> None:
        """Start at the steady state for a constant input x."""
        gain = sum(self.b) / sum(self.a)
        y = gain * x
        n = len(self.z)
        for i in range(n - 1, -1, -1):  # z[i] = sum over k > i of (b[k+1] x - a[k+1] y)
            self.z[i] = (self.b[i + 1] * x - self.a[i + 1] * y) + (self.z[i + 1] if i + 1 < n else 0.0)

    def __call__(self, x: float) -> float:
        b, a, z = self.b, self.a, self.z
        y = b[0] * x + z[0]
        n = len(z)
        for i in range(n - 1):
            z[i] = b[i + 1] * x - a[i + 1] * y + z[i + 1]
        z[n - 1] = b[n] * x - a[n] * y
        return y


class DisturbanceObserver:
    """d_hat per joint from measured angles and the inner controller's outputs."""

    def __init__(self, models: tuple[NominalJoint, ...], dt: float, tau: tuple[float, ...], limit: tuple[float, ...]):
        self.n = len(models)
        self.limit = limit
        self.models = models
        self.delay = [m.delay_steps(dt) for m in models]
        self.u_off = [m.input_offset for m in models]
        self._inverse, self._q = [], []
        for m, t in zip(models, tau):
            plant_den = [m.J * m.T_ep, m.J + m.D * m.T_ep, m.D + m.K * m.T_ep, m.K]  # (J s^2 + D s + K)(T_ep s + 1)
            q_den = [t ** 3, 3 * t ** 2, 3 * t, 1.0]
            num_i, den_i, _ = cont2discrete(([v / m.kt for v in plant_den], q_den), dt, method="bilinear")
            num_q, den_q, _ = cont2discrete(([1.0], q_den), dt, method="bilinear")
            self._inverse.append(_Filter(list(num_i.ravel()), list(den_i)))
            self._q.append(_Filter(list(num_q.ravel()), list(den_q)))
        self._buf = [[0.0] * (d + 1) for d in self.delay]
        self._k = 0
        self.d_hat = [0.0] * self.n

    def reset(self, angles, last_output) -> None:
        """Filters at steady state for these angles and this output, as if at rest."""
        for j in range(self.n):
            self._buf[j] = [float(last_output[j])] * (self.delay[j] + 1)
            self._inverse[j].settle(angles[j])
            self._q[j].settle(last_output[j])
        self._k = 0

    def estimate(self, angles) -> list[float]:
        """d_hat per joint [V] from this cycle's angles (kept in ``d_hat``)."""
        self._k += 1
        for j in range(self.n):
            buf = self._buf[j]
            delayed = buf[self._k % len(buf)]  # written N + 1 cycles ago: the input th now shows
            d = self._inverse[j](angles[j]) - self._q[j](delayed) - self.u_off[j]
            self.d_hat[j] = clamp(d, -self.limit[j], self.limit[j])
        return self.d_hat

    def sent(self, applied) -> None:
        """Remember what was applied this cycle (the delayed input of later cycles)."""
        for j in range(self.n):
            buf = self._buf[j]
            buf[self._k % len(buf)] = applied[j]


class WithDisturbanceObserver(Controller):
    """A controller with the disturbance observer around it: u = u_inner - d_hat.
    Subclasses name the inner controller class; its parameters come first, then dob_*."""

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
        return inner, DisturbanceObserver(self.models, self.context.dt, values["dob_tau"], values["dob_limit"])

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
        self._remember(state.angles, last_output)
        self._taking_over = list(last_output)

    def step(self, state: JointState, reference: Reference) -> list[float]:
        ctx = self.context
        d_hat = self.k.estimate(state.angles)
        if self._taking_over is not None:
            # bumpless: the inner controller takes over the output plus the correction it now meets
            self.inner.reset(state, [u + d for u, d in zip(self._taking_over, d_hat)])
            self._taking_over = None
        u = [v - d for v, d in zip(self.inner.step(state, reference), d_hat)]
        out = [clamp(v, lo, hi) for v, lo, hi in zip(u, ctx.u_min, ctx.u_max)]
        self.k.sent(out)
        self._remember(state.angles, out)
        return out

    def applied(self, output) -> None:
        self.k.sent(output)
        self._last_output = list(output)
        self.inner.applied([u + d for u, d in zip(output, self.k.d_hat)])

    def _remember(self, angles, output) -> None:
        self._last_angles, self._last_output = list(angles), list(output)
