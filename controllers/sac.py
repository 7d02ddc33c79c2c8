"""Simple adaptive control with a parallel feedforward compensator (rig-facts §1, [3-36..3-56]).

Per joint, in SI (rad, V, s):

* reference model, third order with time constant tau_m = 0.02 s: y_m = x_m3,
  G_m(s) = 1 / (tau_m s + 1)^3, driven by u_m = r;
* parallel feedforward compensator (PFC) H(s) = k_f / (tau_f s + 1) added to the plant's
  output, so the augmented plant y_a = y + H u is almost strictly positive real; the thesis's
  gain 2.5 is read in its working unit, deg/V, so k_f = 2.5 pi/180 rad/V; tau_f = 0.05 s
  (bottom) / 0.08 s (middle). The PFC is fed u less its mean over ``washout_s`` (our
  addition): fed the whole u, the augmented output settles k_f u away from the plant's, and
  u holds several volts of spring and bias torque here, a steady error of degrees;
* e_y = y_m - y_a;  r_v = [e_y, x_m1, x_m2, x_m3, u_m, 1];  u = (K_P + K_I) r_v with
  K_P = e_y r_v^T G_P  and  K_I' = e_y r_v^T G_I - sigma(t) K_I,  sigma(t) = s1 e_y^2 + s2
  (sigma-modification keeps the integral gains bounded) [3-44..3-56]. G_P, G_I diagonal: one
  rate for the e_y entry, one for the rest. The constant entry is our addition: it learns
  the spring and bias offset, which the thesis's regressor leaves to the u_m gain.

The plant output y is the angle predicted T_dly ahead by :class:`DelayedStateEstimator`
(the dead time would otherwise break the positive-realness SAC relies on). Gains adapt from
zero except those on u_m and 1, which start at the nominal model's static inverse, and the
transfer is made bumpless by a constant offset that carries the output in force and decays
with time constant ``transfer_s``.
"""
from __future__ import annotations

import math

import numpy as np

from controllers.base import Controller, JointState, ParamSpec, Reference, clamp
from controllers.estimation import ESTIMATOR_PARAMS, DelayedStateEstimator

DEG = math.pi / 180.0


class SAC(Controller):
    """Simple adaptive control with a parallel feedforward compensator and sigma-modification."""

    name = "sac"
    params = (
        ParamSpec("tau_m", "s", 1e-3, 10.0, (0.02, 0.02), "reference model time constant (third order)"),
        ParamSpec("pfc_gain", "deg/V", 0.0, 100.0, (2.5, 2.5), "PFC gain k_f"),
        ParamSpec("pfc_tau", "s", 1e-3, 10.0, (0.05, 0.08), "PFC time constant tau_f"),
        ParamSpec("gamma_pe", "V/rad^2", 0.0, 1e9, (1.0e4, 1.0e4), "proportional adaptation on e_y (G_P)"),
        ParamSpec("gamma_ie", "V/(rad^2 s)", 0.0, 1e9, (1.0e5, 1.0e5), "integral adaptation on e_y (G_I)"),
        ParamSpec("gamma_ix", "V/(rad^2 s)", 0.0, 1e9, (20.0, 20.0), "integral adaptation on x_m, u_m, 1 (G_I)"),
        ParamSpec("sigma1", "1/(rad^2 s)", 0.0, 1e9, (0.0, 0.0), "sigma-modification s1 (on e_y^2)"),
        ParamSpec("sigma2", "1/s", 0.0, 1e3, (1e-3, 1e-3), "sigma-modification s2"),
        ParamSpec("washout_s", "s", 1e-2, 1e4, (1.0, 1.0), "the PFC sees u less its mean over this time"),
        ParamSpec("transfer_s", "s", 1e-3, 100.0, (1.0, 1.0), "decay of the bumpless-transfer offset"),
    ) + ESTIMATOR_PARAMS

    def __init__(self, context, **values):
        self.models = context.require_models("sac")
        n = context.n
        self._xm = np.zeros((n, 3))  # reference model states [rad]
        self._xf = np.zeros(n)  # PFC state [rad]
        self._ki = np.zeros((n, 6))  # integral adaptive gains on [e_y, x_m1..3, u_m, 1]
        self._offset = np.zeros(n)  # bumpless-transfer offset [V]
        super().__init__(context, **values)

    def derive(self, values):
        dt = self.context.dt
        return {
            "am": np.exp(-dt / np.array(values["tau_m"])),
            "af": np.exp(-dt / np.array(values["pfc_tau"])),
            "kf": np.array(values["pfc_gain"]) * DEG,
            "gp": np.column_stack([values["gamma_pe"]] + [[0.0] * self.context.n] * 5),
            "gi": np.column_stack([values["gamma_ie"]] + [values["gamma_ix"]] * 5) * dt,
            "s1": np.array(values["sigma1"]), "s2": np.array(values["sigma2"]),
            "decay": np.exp(-dt / np.array(values["transfer_s"])),
            "aw": np.exp(-dt / np.array(values["washout_s"])),
            "estimator": DelayedStateEstimator.from_params(self.models, dt, values),
        }

    def reset(self, state: JointState, last_output) -> None:
        k = self.k
        k["estimator"].reset(state.angles, last_output)
        q = np.asarray(state.angles, dtype=float)
        self._xm = np.repeat(q[:, None], 3, axis=1)
        self._xf = np.zeros(self.context.n)
        self._u_mean = np.asarray(last_output, dtype=float)
        self._ki = np.zeros((self.context.n, 6))
        for j, m in enumerate(self.models):  # start from the nominal static inverse, V = K th / kt - u_off
            self._ki[j, 4] = m.K / m.kt
            self._ki[j, 5] = -m.input_offset
        self._first = np.asarray(last_output, dtype=float)

    def step(self, state: JointState, reference: Reference) -> list[float]:
        k, ctx = self.k, self.context
        x = k["estimator"].estimate(state.angles)
        r = np.asarray(reference.angles, dtype=float)
        am = k["am"][:, None]
        # three first-order lags in series (exact ZOH of each stage)
        xm = self._xm
        xm[:, 0] = am[:, 0] * xm[:, 0] + (1 - am[:, 0]) * r
        xm[:, 1] = am[:, 0] * xm[:, 1] + (1 - am[:, 0]) * xm[:, 0]
        xm[:, 2] = am[:, 0] * xm[:, 2] + (1 - am[:, 0]) * xm[:, 1]
        e = xm[:, 2] - (x[:, 0] + self._xf)
        rv = np.column_stack([e, xm, r, np.ones_like(r)])
        kp = e[:, None] * k["gp"] * rv
        sigma = k["s1"] * e * e + k["s2"]
        self._ki += e[:, None] * k["gi"] * rv - (sigma * ctx.dt)[:, None] * self._ki
        v = ((kp + self._ki) * rv).sum(axis=1)
        if self._first is not None:  # bumpless: the offset makes this first output the one in force
            self._offset = self._first - v
            self._first = None
        self._offset *= k["decay"]
        u = [clamp(float(a), lo, hi) for a, lo, hi in zip(v + self._offset, ctx.u_min, ctx.u_max)]
        self._pfc_before = (self._u_mean, self._xf)
        self._feed_pfc(u)
        k["estimator"].advance(u)
        return u

    def _feed_pfc(self, u) -> None:
        """The PFC's time update with this cycle's output, washed out (see the module doc)."""
        k, ua = self.k, np.asarray(u, dtype=float)
        self._u_mean = k["aw"] * self._u_mean + (1 - k["aw"]) * ua
        self._xf = k["af"] * self._xf + (1 - k["af"]) * k["kf"] * (ua - self._u_mean)

    def applied(self, output) -> None:
        self._u_mean, self._xf = self._pfc_before
        self._feed_pfc(output)
        self.k["estimator"].replace_last(output)
