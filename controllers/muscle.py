"""Controllers of the antagonistic muscle joint (rig-facts §2): angle and stiffness as live
set-points, the two muscle pressures [Pa] (and the MR brake's torque [N m]) as commands.

``muscle_eq``, the model-based one. The mechanical-equilibrium model [4.17, 4.18]
(:meth:`hal.muscle.MusclePair.equilibrium`) gives the pressure pair that holds the set-point
angle with the desired stiffness K_d against gravity and the known tip load; feedback on
the angle adds a torque ``tau_fb`` that the same model turns into pressures at the same
stiffness::

    tau_fb = Kp (th_m - th) + Kp Td (w_m - w) + I,    dI/dt = (Kp / Ti) e_c,    Kp = feedback K_d
    e_c    = th_m + tau_ext / K_d - th      (``compliant`` = 1, the default)
    e_c    = th_m - th                      (``compliant`` = 0: position control)

where th_m, w_m is the reference model: the set-point through two first-order lags of
``response`` seconds, each fed the reference's own speed w_r as well,

    th_1' = (th_r - th_1) / response + w_r,    th_m' = (th_1 - th_m) / response + w_r,

a critically damped response to a step that the valves' dead time and the chambers' filling
let the arm follow (a 2-DOF design: the model is fed forward through the equilibrium model at
th_m, the feedback only corrects the arm's deviation from it). A step then asks the arm for a
move it can make, whatever its size, so the feedback and the integral do not wind up on the
lag of a step the arm has not made yet (which would overshoot a long step and leave a slow
tail); a planned trajectory, whose speed is fed through, passes without the lag.

``tau_ext`` is the external torque the measured muscle pressures show beyond gravity and the
known load (low-passed). Integrating ``e_c`` rather than the plain error corrects the model's
errors while leaving the joint exactly as compliant as commanded: at rest an unknown load
deflects it by tau_ext / K_d, not by zero (that is what stiffness control is for) and not by
tau_ext / (K_d + Kp) either.

``muscle_pid``, the plain variant: PID on the angle error gives the pressure difference,
``P_a,b = P_mean +- dP / 2``, with the mean pressure that gives K_d at mid-stroke; no model of
gravity or load.

Both can damp with the MR brake: a braking torque ``brake_linear |w| + brake_quadratic w^2``
(Fig. 4.25's two laws; 0: off), which the brake applies against the motion.
"""
from __future__ import annotations

import math

from controllers.base import Controller, JointState, ParamError, ParamSpec, Reference, SignalSpec, clamp

DEG = 180.0 / math.pi
EXTERNAL_FILTER_HZ = 5.0  # the external-torque estimate's low-pass


def _stiffness_param(default_nm_deg: float) -> ParamSpec:
    """In N m/deg, the unit ``set --stiffness`` and the protocol's ``stiffness_nm_deg`` take (a
    user compares the two numbers); turned to N m/rad where the control law uses it."""
    return ParamSpec("stiffness", "N m/deg", 0.05, 3.0, (default_nm_deg,),
                     "joint stiffness when the set-point gives none")


BRAKE_PARAMS = (
    ParamSpec("brake_linear", "N m s/rad", 0.0, 100.0, (0.0,), "MR brake torque per joint speed (0: off)"),
    ParamSpec("brake_quadratic", "N m s^2/rad^2", 0.0, 100.0, (0.0,), "MR brake torque per speed squared (0: off)"),
)


class MuscleController(Controller):
    """What both muscle controllers share: the command layout, the stiffness set-point, the brake."""

    actuation = "muscle_pair"

    def __init__(self, context, **values):
        self._check_actuation(context)
        self._joints = []  # (joint index, first command index, model, has brake)
        k = 0
        for i, model in enumerate(context.muscles or [None] * context.n):
            if model is None:
                raise ParamError(f"{self.name}: joint {context.joint_names[i]!r} has no muscle model")
            has_brake = model.brake_max_nm > 0.0
            self._joints.append((i, k, model, has_brake))
            k += 3 if has_brake else 2
        self._out = [0.0] * context.width
        self._k_set = [0.0] * context.n  # this cycle's stiffness set-point [N m/rad]
        super().__init__(context, **values)

    def derive(self, values):
        for (i, _, _, has_brake), lin, quad in zip(self._joints, values["brake_linear"], values["brake_quadratic"]):
            if (lin or quad) and not has_brake:
                raise ParamError(f"{self.name}.brake_linear[{self.context.joint_names[i]}]: this joint has no brake")
        return None

    def stiffness_setpoint(self, reference: Reference, j: int) -> float:
        """K_d [N m/rad]: the reference's, else the ``stiffness`` parameter's [N m/deg]."""
        k = reference.stiffness[j] if len(reference.stiffness) > j else math.nan
        return k if k == k else self.p("stiffness")[j] * DEG

    def brake(self, j: int, w: float) -> float:
        return self.p("brake_linear")[j] * abs(w) + self.p("brake_quadratic")[j] * w * w


class MuscleEquilibrium(MuscleController):
    """Angle + stiffness through the mechanical-equilibrium model, with compliant feedback."""

    name = "muscle_eq"
    params = (
        _stiffness_param(0.3),
        ParamSpec("tip_load", "N", 0.0, 200.0, (0.0,), "the known weight at the tip the model holds"),
        ParamSpec("feedback", "-", 0.0, 5.0, (0.3,), "feedback stiffness Kp on the angle error, as a fraction of "
                  "the commanded stiffness (the loop's gain then follows it: the valves' 40 ms dead time "
                  "bounds it)"),
        ParamSpec("Td", "s", 0.0, 1.0, (0.02,), "derivative time on the speed error"),
        ParamSpec("Ti", "s", 0.0, 100.0, (0.375,), "integral time; 0: off"),
        ParamSpec("response", "s", 0.001, 10.0, (0.27,), "time constant of the reference model: the set-point "
                  "reaches the feed-forward and the feedback through two lags of this"),
        ParamSpec("compliant", "-", 0.0, 1.0, (1.0,), "1: the integral acts on the compliant error, so the "
                  "joint at rest is as stiff as commanded; 0: on the angle error, so it returns to its "
                  "set-point under any static load (position control)"),
        *BRAKE_PARAMS,
    )
    internals = (SignalSpec("stiffness_set", "N m/rad", "the stiffness commanded"),
                 SignalSpec("stiffness", "N m/rad", "the muscles' stiffness at the measured pressures"),
                 SignalSpec("tau_ext", "N m", "external torque the measured pressures show"),
                 SignalSpec("i", "N m", "integral torque"),
                 SignalSpec("brake", "N m", "MR brake torque commanded"))

    def __init__(self, context, **values):
        self._i = [0.0] * context.n  # integral torque [N m]
        self._ext = [0.0] * context.n  # filtered external torque [N m]
        self._k_meas = [0.0] * context.n
        self._q_m = [0.0] * context.n  # the reference model's angle [rad]
        self._q_1 = [0.0] * context.n  # its first lag's output [rad]
        self._a_ext = -math.expm1(-2 * math.pi * EXTERNAL_FILTER_HZ * context.dt)
        super().__init__(context, **values)

    def derive(self, values):
        """Per joint, the update gain of the reference model's lags at the loop period."""
        super().derive(values)
        return tuple(-math.expm1(-self.context.dt / r) for r in values["response"])

    def reset(self, state: JointState, last_output) -> None:
        """Bumpless in torque: the integral takes up what the output in force gives beyond the
        model's holding torque (none when the muscles were vented, as on enable)."""
        self._out[:] = [float(u) for u in last_output]
        for j, (i, k, model, _) in enumerate(self._joints):
            q = state.angles[i]
            pa, pb = last_output[k], last_output[k + 1]
            self._ext[j], self._q_m[j], self._q_1[j] = 0.0, q, q
            if pa > 1e3 or pb > 1e3:
                self._i[j] = model.pair.torque(pa, pb, q) + model.gravity_torque(q, self.p("tip_load")[j])
            else:
                self._i[j] = 0.0

    def step(self, state: JointState, reference: Reference) -> list[float]:
        out, h = self._out, self.context.dt
        ratio, td, ti, load, compliant = (self.p("feedback"), self.p("Td"), self.p("Ti"), self.p("tip_load"),
                                          self.p("compliant"))
        lag, response = self.k, self.p("response")
        for j, (i, k, model, has_brake) in enumerate(self._joints):
            q, w = state.angles[i], state.velocities[i]
            q_r = reference.angles[i]
            k_d = self.stiffness_setpoint(reference, j)
            self._k_set[j] = k_d
            pair = model.pair
            if len(state.pressures) > 2 * i + 1 and state.pressures[2 * i] == state.pressures[2 * i]:
                pa_m, pb_m = state.pressures[2 * i], state.pressures[2 * i + 1]
                external = -(pair.torque(pa_m, pb_m, q) + model.gravity_torque(q, load[j]))
                self._ext[j] += self._a_ext * (external - self._ext[j])
                self._k_meas[j] = pair.stiffness(pa_m, pb_m, q)
            kp = ratio[j] * k_d
            w_r = reference.velocities[i]
            self._q_1[j] += lag[j] * (q_r - self._q_1[j]) + h * w_r
            self._q_m[j] += lag[j] * (self._q_1[j] - self._q_m[j]) + h * w_r
            q_m = self._q_m[j]
            w_m = (self._q_1[j] - q_m) / response[j] + w_r
            tau_fb = kp * (q_m - q + td[j] * (w_m - w)) + self._i[j]
            pa, pb = pair.equilibrium(q_m, k_d, tau_fb - model.gravity_torque(q_m, load[j]))
            lo, hi = self.u_lo[k], self.u_hi[k]
            saturated = not (lo < pa < hi and lo < pb < hi)
            if ti[j] > 0.0:
                e_c = q_m - q + (self._ext[j] / k_d if compliant[j] >= 0.5 else 0.0)
                # conditional integration: never further into a pressure limit
                if not saturated or (e_c > 0) != (pa >= hi or pb <= lo):
                    self._i[j] += kp * h / ti[j] * e_c
            out[k] = clamp(pa if pa == pa else lo, lo, hi)
            out[k + 1] = clamp(pb if pb == pb else lo, lo, hi)
            if has_brake:
                out[k + 2] = clamp(self.brake(j, w), 0.0, self.u_hi[k + 2])
        return out

    def internal_signals(self) -> list[list[float]]:
        brakes = [self._out[k + 2] if b else 0.0 for _, k, _, b in self._joints]
        return [list(self._k_set), list(self._k_meas), list(self._ext), list(self._i), brakes]


class MusclePID(MuscleController):
    """PID on the angle error to the muscles' pressure difference, the mean set by the stiffness."""

    name = "muscle_pid"
    params = (
        _stiffness_param(0.3),
        ParamSpec("Kp", "Pa/rad", 0.0, 1.0e7, (2.0e5,), "pressure difference per rad of error"),
        ParamSpec("Ti", "s", 0.0, 100.0, (0.3,), "integral time; 0: off"),
        ParamSpec("Td", "s", 0.0, 10.0, (0.03,), "derivative time"),
        *BRAKE_PARAMS,
    )
    internals = (SignalSpec("dp", "Pa", "pressure difference a - b commanded"),
                 SignalSpec("mean", "Pa", "mean pressure (from the stiffness)"),
                 SignalSpec("i", "Pa", "integral part"))

    def __init__(self, context, **values):
        self._i = [0.0] * context.n  # [Pa]
        self._dp = [0.0] * context.n
        self._mean = [0.0] * context.n
        super().__init__(context, **values)
        # the pair's stiffness per Pa of P_a + P_b at mid-stroke [N m/rad/Pa]
        self._per_pa = [m.pair.n * m.pair.radius ** 2 / m.pair.length * m.pair.slope(m.pair.eps_c)
                        for _, _, m, _ in self._joints]

    def reset(self, state: JointState, last_output) -> None:
        self._out[:] = [float(u) for u in last_output]
        for j, (i, k, _, _) in enumerate(self._joints):
            self._i[j] = last_output[k] - last_output[k + 1]  # the difference in force carries on

    def step(self, state: JointState, reference: Reference) -> list[float]:
        out, h = self._out, self.context.dt
        kp, ti, td = self.p("Kp"), self.p("Ti"), self.p("Td")
        for j, (i, k, _, has_brake) in enumerate(self._joints):
            e = reference.angles[i] - state.angles[i]
            mean = 0.5 * self.stiffness_setpoint(reference, j) / self._per_pa[j]
            dp = kp[j] * e + kp[j] * td[j] * (reference.velocities[i] - state.velocities[i]) + self._i[j]
            lo, hi = self.u_lo[k], self.u_hi[k]
            pa, pb = mean + 0.5 * dp, mean - 0.5 * dp
            if ti[j] > 0.0 and (lo < pa < hi and lo < pb < hi or (e > 0) != (pa >= hi or pb <= lo)):
                self._i[j] += kp[j] * h / ti[j] * e
            self._dp[j], self._mean[j] = dp, mean
            out[k], out[k + 1] = clamp(pa, lo, hi), clamp(pb, lo, hi)
            if has_brake:
                out[k + 2] = clamp(self.brake(j, state.velocities[i]), 0.0, self.u_hi[k + 2])
        return out

    def internal_signals(self) -> list[list[float]]:
        return [list(self._dp), list(self._mean), list(self._i)]
