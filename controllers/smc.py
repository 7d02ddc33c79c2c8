"""Servo-type sliding mode control (rig-facts §1, [3-57..3-90]).

The state is extended with the integral of the tracking error, x = [z, th, th', th''] with
z' = r - th, so the plant of [2-43] (see :mod:`controllers.nominal`) becomes

    x' = A_e x + B_e u + E r,   A_e = [[0, -1, 0, 0], [0, A]],   B_e = [0, B],   E = [1, 0, 0, 0].

Switching function sigma = S x. On sigma = 0 the motion obeys the hyperplane's own dynamics,
whatever the plant's; S comes from the optimal design of [3-70..3-80]: the system is in
regular form (B_e acts on th'' only), so th'' is the virtual input of x1 = [z, th, th'] and
S = [K, 1] with K = R^-1 A12^T P, P solving the Riccati equation of (A11 + eps I, A12, Q, R).
The shift eps puts every sliding pole left of -eps.

    u = -(S B_e)^-1 (S A_e x + S E r)  -  k (S B_e)^-1 sigma / (|sigma| + eta)    [3-84..3-90]
        - lambda (S B_e)^-1 sigma

The first term is the equivalent control, the second the switching part smoothed by the
boundary layer eta; the third, a proportional reaching term (Gao & Hung's reaching law, our
addition), brings sigma back even when a disturbance outgrows the switching amplitude, so
the integral state can then remove the steady error. Here its amplitude k (S B_e)^-1 is the parameter ``switch_volts`` [V];
stability needs it to exceed the input-equivalent disturbance bound, k > |S d_max| [3-94]:
at least the breakaway friction in volts, Fs / kt, which is 0.31 V on the bottom joint and
1.66 V on the middle one (defaults 1 V and 3 V). Below it the middle joint sticks, breaks
away, and overshoots by degrees before sigma turns the output round (4.5 deg on the circle
at 1 V). A faster integral (q_z) cures that too but makes the middle joint's step ring.

**Keep the plant's damping (our tuning, after the thesis's legible S).** The joints are
heavily overdamped (D/J = 331 1/s bottom, 1440 1/s middle). The equivalent control cancels
whatever of the plant's dynamics the hyperplane does not ask for: with a velocity weight
k2 = S[2] far below D/J it cancels the damping, the loop then rests on the reaching part
alone, and a saturated output turns that cancellation into positive velocity feedback (a
joint pushed past the rig's authority ran away into its limit, and swung limit to limit
after). So q_w is chosen to put k2 at about D/J, as the thesis's own S does (354.7 against
331 on the bottom joint, normalised on th''), and q_z, q_th to put the two slow sliding poles
where they were (-9.3 +- 8.2j bottom, -2.7 +- 2.2j middle); the fast pole sits at -D/J.

**Anti-windup (conditional integration).** While the output is clamped, z integrates only
when that draws the output back into range (v moves as -s0 e); otherwise it is held.

Units: rad, rad/s, rad/s^2; sigma in rad/s^2 (S normalised so its th'' entry is 1); u = V_MV
[V]. The state comes from :class:`controllers.estimation.DelayedStateEstimator`: the plant's
dead time is not in [2-43], so the control acts on the state predicted T_dly ahead (our
addition; without it the thesis's hyperplane, with poles near -20 rad/s, would not survive
the bottom joint's 81 ms delay). The constant spring and bias torques are fed forward.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_continuous_are

from controllers.base import (
    Controller,
    JointState,
    ParamError,
    ParamSpec,
    Reference,
    SignalSpec,
)
from controllers.dob import D_HAT, DOB_PARAMS, WithDisturbanceObserver
from controllers.estimation import ESTIMATOR_PARAMS, DelayedStateEstimator

A11 = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])  # x1 = [z, th, th']
A12 = np.array([[0.0], [0.0], [1.0]])  # th'' drives th'


def sliding_hyperplane(q_z: float, q_th: float, q_w: float, eps: float, r: float = 1.0) -> np.ndarray:
    """S = [K, 1] of the optimal hyperplane [3-70..3-80]: K = R^-1 A12^T P with P from
    (A11 + eps I)^T P + P (A11 + eps I) - P A12 R^-1 A12^T P + Q = 0, Q = diag(q_z, q_th, q_w)."""
    if q_z <= 0:
        raise ParamError("the hyperplane needs a positive weight on the error integral (q_z > 0)")
    p = solve_continuous_are(A11 + eps * np.eye(3), A12, np.diag([q_z, q_th, q_w]), np.array([[r]]))
    k = (A12.T @ p / r).ravel()
    return np.append(k, 1.0)


def sliding_poles(s: np.ndarray) -> np.ndarray:
    """Poles of the motion on sigma = 0 (th'' = -K x1): eigenvalues of A11 - A12 K."""
    return np.linalg.eigvals(A11 - A12 @ (s[:3] / s[3])[None, :])


@dataclass(frozen=True)
class _Design:
    s: list[np.ndarray]  # hyperplane per joint
    sa: list[tuple[float, float, float]]  # S A_e per joint, on [th, th', th''] (the z column is 0)
    sb: list[float]  # S B_e [rad/s^3 per V]
    switch: tuple[float, ...]  # [V]
    eta: tuple[float, ...]  # [rad/s^2]
    reach: tuple[float, ...]  # [1/s]
    estimator: DelayedStateEstimator

    def per_joint(self) -> tuple[tuple[float, ...], ...]:
        """What step() reads per joint, as plain floats (numpy scalars cost several times more):
        (S, SA, SB, k, eta, lambda)."""
        return tuple((*map(float, s), *sa, sb, k, eta, reach) for s, sa, sb, k, eta, reach
                     in zip(self.s, self.sa, self.sb, self.switch, self.eta, self.reach))


class SMC(Controller):
    """Servo-type sliding mode control with an optimal hyperplane and a boundary layer."""

    name = "smc"
    params = (
        # defaults tuned on the reconstructed rig's paths at the thesis's durations (issue 32,
        # docs/controllers.md), and for an output pinned at a limit to recover without swinging to
        # the other (tests/test_saturation.py)
        ParamSpec("q_z", "1/s^6", 1e-6, 1e15, (5.0e10, 5.0e9), "LQ weight on the error integral (relative to th'')"),
        ParamSpec("q_th", "1/s^4", 0.0, 1e12, (2.0e5, 3.0e4), "LQ weight on the angle"),
        ParamSpec("q_w", "1/s^2", 0.0, 1e9, (1.1e5, 1.1e5),
                  "LQ weight on the velocity; about (D/J)^2 keeps the plant's own damping (see the module doc)"),
        ParamSpec("eps", "1/s", 0.0, 100.0, (2.0, 1.5), "Riccati shift: every sliding pole left of -eps"),
        ParamSpec("switch_volts", "V", 0.0, 10.0, (1.0, 3.0),
                  "switching amplitude k (S B)^-1; above the breakaway friction Fs/kt (0.31 V bottom, 1.66 V middle)"),
        # the middle joint's is 7.5 times the bottom's: on the reconstructed rig a volt moves its sigma
        # 7.5 times as much (its J, D, K per 7.5 deg, hal/models.toml middle-scaled), and at 2 rad/s^2 the
        # switching part's slope k/eta closed a loop that alternated the output every cycle (0.4-0.8 V
        # peak to peak at 500 Hz while holding, docs/controllers.md "Robustness")
        ParamSpec("boundary", "rad/s^2", 1e-6, 1e6, (2.0, 15.0), "boundary layer eta of sigma/(|sigma|+eta)"),
        ParamSpec("reach_rate", "1/s", 0.0, 1e4, (5.0, 5.0), "proportional reaching term: sigma' = -reach_rate sigma"),
    ) + ESTIMATOR_PARAMS
    internals = (SignalSpec("sigma", "rad/s^2", "switching function S x"),
                 SignalSpec("u_eq", "V", "equivalent control"),
                 SignalSpec("u_reach", "V", "switching and reaching part"),
                 SignalSpec("z", "rad s", "integral of the tracking error"))

    def __init__(self, context, **values):
        self.models = context.require_models("smc")
        super().__init__(context, **values)
        self._z = [0.0] * context.n
        self._sigma = [0.0] * context.n
        self._u_eq = [0.0] * context.n
        self._u_reach = [0.0] * context.n
        self._taking_over: list[float] | None = None

    def derive(self, values) -> _Design:
        designs, sa, sb = [], [], []
        for j, m in enumerate(self.models):
            s = sliding_hyperplane(values["q_z"][j], values["q_th"][j], values["q_w"][j], values["eps"][j])
            a, b = m.state_space()
            a_e = np.zeros((4, 4))
            a_e[0, 1] = -1.0
            a_e[1:, 1:] = a
            row = s @ a_e
            designs.append(s)
            sa.append((float(row[1]), float(row[2]), float(row[3])))
            sb.append(float(s[3] * b[2, 0]))
        return _Design(designs, sa, sb, values["switch_volts"], values["boundary"], values["reach_rate"],
                       DelayedStateEstimator.from_params(self.models, self.context.dt, values))

    def reset(self, state: JointState, last_output) -> None:
        self.k.estimator.reset(state.angles, last_output)
        self._z = [0.0] * self.context.n
        self._taking_over = [float(u) for u in last_output]

    def apply_params(self, prepared) -> None:
        super().apply_params(prepared)
        self._joints = self.k.per_joint()

    def step(self, state: JointState, reference: Reference) -> list[float]:
        dt, z, estimator = self.context.dt, self._z, self.k.estimator
        x = estimator.estimate(state.angles)
        out = []
        for j, (s0, s1, s2, s3, sa0, sa1, sa2, sb, k, eta, reach) in enumerate(self._joints):
            th, w, acc = x[j]
            r = reference.angles[j]
            u_eq = -(sa0 * th + sa1 * w + sa2 * acc + s0 * r) / sb - estimator.u_off[j]
            rest = s1 * th + s2 * w + s3 * acc
            if self._taking_over is not None:  # bumpless: choose z so that u equals the output in force
                z[j] = _integral_for(self._taking_over[j] - u_eq, self.k, j, rest)
            sigma = s0 * z[j] + rest
            reaching = -k * sigma / (abs(sigma) + eta) - reach * sigma / sb
            v = u_eq + reaching
            self._sigma[j], self._u_eq[j], self._u_reach[j] = sigma, u_eq, reaching
            lo, hi = self.u_lo[j], self.u_hi[j]
            u = lo if v < lo else hi if v > hi else v
            e = r - th
            # conditional integration: while clamped, z moves only if it draws v back into range.
            # v falls as sigma rises (SB > 0), and z' = e moves sigma by s0 e, so v moves as -s0 e.
            if u == v or (u > v) == (s0 * e < 0):
                z[j] += e * dt
            out.append(u)
        self._taking_over = None
        estimator.advance(out)
        return out

    def applied(self, output) -> None:
        self.k.estimator.replace_last(output)

    def internal_signals(self) -> list[list[float]]:
        return [list(self._sigma), list(self._u_eq), list(self._u_reach), list(self._z)]


def _integral_for(target: float, d: _Design, j: int, rest: float) -> float:
    """The z that makes the reaching part -k sigma/(|sigma|+eta) - lambda sigma/SB equal
    ``target`` [V] (it falls monotonically in sigma): bisection on sigma."""
    def part(sigma):
        return -d.switch[j] * sigma / (abs(sigma) + d.eta[j]) - d.reach[j] * sigma / d.sb[j]
    lo, hi = -1e6, 1e6
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if part(mid) > target else (lo, mid)
    return (0.5 * (lo + hi) - rest) / float(d.s[j][0])  # a plain float: a numpy scalar in z slows every step


class SMCWithDOB(WithDisturbanceObserver):
    """Servo-type SMC with the disturbance observer subtracting the estimated input disturbance."""

    name = "smc_dob"
    inner_class = SMC
    params = SMC.params + DOB_PARAMS
    internals = SMC.internals + (D_HAT,)
