"""Simple adaptive control with a parallel feedforward compensator (rig-facts §1, [3-36..3-56]).

Per joint, in SI (rad, V, s):

* reference model, third order with time constant tau_m = 0.02 s: y_m = x_m3,
  G_m(s) = 1 / (tau_m s + 1)^3, driven by u_m = r;
* parallel feedforward compensator (PFC) H(s) = k_f / (tau_f s + 1) added to the plant's
  output, so the augmented plant y_a = y + H u is almost strictly positive real (ASPR);
  tau_f = 0.05 s (bottom) / 0.08 s (middle) as in the thesis. The PFC is fed u less its mean
  over ``washout_s`` (our addition): fed the whole u, the augmented output settles k_f u away
  from the plant's, and u holds several volts of spring and bias torque here;
* k_f defaults to 0.5 deg/V, a fifth of the thesis's 2.5 (read in its working unit, deg/V)
  (our choice): SAC drives e_y, not the plant's error, so whatever the PFC adds while u swings
  is tracking error, measured at 5 deg on the middle joint with 2.5. G + H is ASPR when
  H^-1 = (tau_f s + 1)/k_f stabilises the nominal plant of [2-43]; Routh on
  (J s^2 + D s + K)(T_ep s + 1) k_f + kt (tau_f s + 1) holds for every k_f > 0 on both joints
  (the viscous term dominates: (J + D T_ep) tau_f > J T_ep), so the smaller gain keeps the
  guarantee. docs/controllers.md has the sweep;
* e_y = y_m - y_a;  r_v = [e_y, x_m1, x_m2, x_m3, u_m, 1];  u = (K_P + K_I) r_v with
  K_P = e_y r_v^T G_P  and  K_I' = e_y r_v^T G_I - sigma(t) K_I,  sigma(t) = s1 e_y^2 + s2
  (sigma-modification keeps the integral gains bounded) [3-44..3-56]. G_P, G_I diagonal: one
  rate for the e_y entry, one for the rest. The constant entry is our addition: it learns
  the spring and bias offset, which the thesis's regressor leaves to the u_m gain;
* u += k_s e_y / (|e_y| + delta), a smoothed switching term (our addition, as in SMC's
  reaching law): with k_s above the breakaway friction Fs/kt (rig-facts §1 friction [2-45]:
  0.31 V bottom, 1.66 V middle) a stuck joint breaks away on a small error instead of
  waiting for the adaptive integral to grow;
* no adaptation while |e_y| is within ``adapt_deadzone`` (the dead-zone modification of
  robust adaptive control, our addition; 0.17 deg on the middle joint by default): holding
  against a disturbance, the middle joint otherwise hunts in a +-0.6 deg stick-slip cycle,
  its integral gains ramping while friction holds it and overshooting when it breaks away;
* anti-windup by conditional adaptation (our addition): while the output sits at a limit, the
  integral gains do not learn in the direction that drives it further in (the sigma leak
  goes on), so the gains are where they were when the reference comes back into reach.

The plant output y is the angle predicted T_dly ahead by :class:`DelayedStateEstimator`
(the dead time would otherwise break the positive-realness SAC relies on). Gains adapt from
zero except those on u_m and 1, which start at the nominal model's static inverse, and the
transfer is made bumpless by a constant offset that carries the output in force and decays
with time constant ``transfer_s``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from controllers.base import Controller, JointState, ParamSpec, Reference, SignalSpec
from controllers.estimation import ESTIMATOR_PARAMS, DelayedStateEstimator

DEG = math.pi / 180.0


@dataclass(frozen=True)
class _Constants:
    """Per joint, at the loop period."""

    am: tuple[float, ...]  # reference model pole, exp(-dt / tau_m)
    af: tuple[float, ...]  # PFC pole
    kf: tuple[float, ...]  # PFC gain [rad/V]
    gp: tuple[float, ...]  # G_P on e_y [V/rad^2]
    gi_e: tuple[float, ...]  # G_I dt on e_y
    gi_x: tuple[float, ...]  # G_I dt on x_m, u_m, 1
    s1: tuple[float, ...]
    s2: tuple[float, ...]
    decay: tuple[float, ...]  # of the transfer offset, per cycle
    aw: tuple[float, ...]  # washout pole
    switch: tuple[float, ...]  # [V]
    deadzone: tuple[float, ...]  # [rad]
    boundary: tuple[float, ...]  # [rad]
    estimator: DelayedStateEstimator


class SAC(Controller):
    """Simple adaptive control with a parallel feedforward compensator and sigma-modification."""

    name = "sac"
    params = (
        ParamSpec("tau_m", "s", 1e-3, 10.0, (0.02, 0.02), "reference model time constant (third order)"),
        ParamSpec("pfc_gain", "deg/V", 1e-3, 100.0, (0.5, 0.5), "PFC gain k_f (the thesis: 2.5)"),
        ParamSpec("pfc_tau", "s", 1e-3, 10.0, (0.05, 0.08), "PFC time constant tau_f"),
        ParamSpec("gamma_pe", "V/rad^2", 0.0, 1e9, (1.0e4, 1.0e4), "proportional adaptation on e_y (G_P)"),
        ParamSpec("gamma_ie", "V/(rad^2 s)", 0.0, 1e9, (1.0e5, 1.0e5), "integral adaptation on e_y (G_I)"),
        ParamSpec("gamma_ix", "V/(rad^2 s)", 0.0, 1e9, (20.0, 20.0), "integral adaptation on x_m, u_m, 1 (G_I)"),
        ParamSpec("sigma1", "1/(rad^2 s)", 0.0, 1e9, (0.0, 0.0), "sigma-modification s1 (on e_y^2)"),
        ParamSpec("sigma2", "1/s", 0.0, 1e3, (1e-3, 1e-3), "sigma-modification s2"),
        ParamSpec("washout_s", "s", 1e-2, 1e4, (1.0, 1.0), "the PFC sees u less its mean over this time"),
        ParamSpec("transfer_s", "s", 1e-3, 100.0, (1.0, 1.0), "decay of the bumpless-transfer offset"),
        ParamSpec("switch_volts", "V", 0.0, 10.0, (0.5, 2.0),
                  "smoothed switching term k_s on e_y (our addition): above the breakaway friction Fs/kt "
                  "(0.31 V bottom, 1.66 V middle)"),
        ParamSpec("adapt_deadzone", "rad", 0.0, 0.1, (0.0, 0.003),
                  "dead-zone modification: no adaptation while |e_y| is below this (our addition)"),
        ParamSpec("switch_boundary", "rad", 1e-6, 1.0, (0.01, 0.01), "boundary layer delta of the switching term"),
    ) + ESTIMATOR_PARAMS
    internals = (SignalSpec("e_y", "rad", "augmented error y_m - (y + PFC)"),
                 SignalSpec("k_e", "V/rad", "integral adaptive gain on e_y"),
                 SignalSpec("k_um", "V/rad", "integral adaptive gain on the reference u_m"),
                 SignalSpec("k_1", "V", "integral adaptive gain on the constant (spring and bias offset)"),
                 SignalSpec("pfc", "rad", "parallel feedforward compensator output"))

    def __init__(self, context, **values):
        self.models = context.require_models("sac")
        n = context.n
        self._e_y = [0.0] * n
        self._xm = [[0.0] * 3 for _ in range(n)]  # reference model states [rad]
        self._xf = [0.0] * n  # PFC state [rad]
        self._ki = [[0.0] * 6 for _ in range(n)]  # integral adaptive gains on [e_y, x_m1..3, u_m, 1]
        self._offset = [0.0] * n  # bumpless-transfer offset [V]
        self._u_mean = [0.0] * n  # the output's washout mean [V]
        self._first: list[float] | None = None
        super().__init__(context, **values)

    def derive(self, values) -> _Constants:
        dt = self.context.dt

        def decay(key):
            return tuple(math.exp(-dt / v) for v in values[key])

        return _Constants(am=decay("tau_m"), af=decay("pfc_tau"), kf=tuple(v * DEG for v in values["pfc_gain"]),
                          gp=values["gamma_pe"], gi_e=tuple(v * dt for v in values["gamma_ie"]),
                          gi_x=tuple(v * dt for v in values["gamma_ix"]), s1=values["sigma1"], s2=values["sigma2"],
                          decay=decay("transfer_s"), aw=decay("washout_s"),
                          switch=values["switch_volts"], boundary=values["switch_boundary"],
                          deadzone=values["adapt_deadzone"],
                          estimator=DelayedStateEstimator.from_params(self.models, dt, values))

    def reset(self, state: JointState, last_output) -> None:
        self.k.estimator.reset(state.angles, last_output)
        n = self.context.n
        self._xm = [[float(q)] * 3 for q in state.angles]
        self._xf = [0.0] * n
        self._u_mean = [float(u) for u in last_output]
        # gains adapt from zero, but the static ones start at the nominal inverse, V = K th / kt - u_off
        self._ki = [[0.0, 0.0, 0.0, 0.0, m.K / m.kt, -m.input_offset] for m in self.models]
        self._first = [float(u) for u in last_output]

    def apply_params(self, prepared) -> None:
        super().apply_params(prepared)
        k = self.k  # what step() reads per joint, as one tuple of plain floats
        self._joints = tuple(zip(k.am, k.s1, k.s2, k.gi_e, k.gi_x, k.gp, k.switch, k.boundary, k.decay, k.deadzone))

    def step(self, state: JointState, reference: Reference) -> list[float]:
        k, dt = self.k, self.context.dt
        predicted = k.estimator.estimate(state.angles)
        out = []
        e_y, xf, offset, first = self._e_y, self._xf, self._offset, self._first
        for j, (a, s1, s2, gi_e, gi_x, gp, switch, boundary, decay, deadzone) in enumerate(self._joints):
            r = reference.angles[j]
            xm = self._xm[j]  # three first-order lags in series (exact ZOH of each stage)
            xm[0] = m0 = a * xm[0] + (1 - a) * r
            xm[1] = m1 = a * xm[1] + (1 - a) * m0
            xm[2] = m2 = a * xm[2] + (1 - a) * m1
            e = e_y[j] = m2 - (predicted[j][0] + xf[j])
            # the regressor r_v = (e, x_m1, x_m2, x_m3, u_m, 1), written out
            ki = self._ki[j]
            leak = (s1 * e * e + s2) * dt  # sigma-modification
            v = gp * e * e * e  # the proportional gain acts on e_y only: (e G_P e) e
            v += switch * e / (abs(e) + boundary)  # breaks stiction
            v += ki[0] * e
            v += ki[1] * m0
            v += ki[2] * m1
            v += ki[3] * m2
            v += ki[4] * r
            v += ki[5] * 1.0
            if first is not None:  # bumpless: the offset makes this first output the one in force
                offset[j] = first[j] - v
            offset[j] *= decay
            v += offset[j]
            lo, hi = self.u_lo[j], self.u_hi[j]
            u = lo if v < lo else hi if v > hi else v
            out.append(u)
            # dead-zone modification: no learning from noise and stiction; and none that winds the
            # output further into a limit (learning moves v by e sum(G rv^2), the sign of e)
            learn = e if abs(e) > deadzone and (u == v or (u > v) == (e > 0)) else 0.0
            ki[0] += learn * gi_e * e - leak * ki[0]
            ki[1] += learn * gi_x * m0 - leak * ki[1]
            ki[2] += learn * gi_x * m1 - leak * ki[2]
            ki[3] += learn * gi_x * m2 - leak * ki[3]
            ki[4] += learn * gi_x * r - leak * ki[4]
            ki[5] += learn * gi_x * 1.0 - leak * ki[5]
        self._first = None
        for j, uj in enumerate(out):  # the PFC's time update, fed the washed-out output
            self._u_mean[j] = k.aw[j] * self._u_mean[j] + (1 - k.aw[j]) * uj
            self._xf[j] = k.af[j] * self._xf[j] + (1 - k.af[j]) * k.kf[j] * (uj - self._u_mean[j])
        self._sent = out
        k.estimator.advance(out)
        return out

    def applied(self, output) -> None:
        """The PFC update is linear in the newest output: move it by what was applied instead."""
        k = self.k
        for j, (mine, real) in enumerate(zip(self._sent, output)):
            change = real - mine
            self._u_mean[j] += (1 - k.aw[j]) * change
            self._xf[j] += (1 - k.af[j]) * k.kf[j] * k.aw[j] * change
        k.estimator.replace_last(output)

    def internal_signals(self) -> list[list[float]]:
        return [list(self._e_y), [g[0] for g in self._ki], [g[4] for g in self._ki], [g[5] for g in self._ki],
                list(self._xf)]
