"""Discrete LTI state-space controller from a design file (rig-facts §1 "mu-synthesis"), and
the same with the disturbance observer.

Per joint, at the loop period (see :mod:`controllers.lti_design` for the file and c2d):

    e = r - th [rad],   u = gain (C x + D e),   x <- A x + B e,   u = V_MV [V].

All joints run as one block-diagonal system, so a cycle is two small matrix products.
``gain`` scales the design's output (the K_tune of rig-facts' robust view) and can change
live. Bumpless transfer: on its first cycle the controller puts its state where the output
equals the one in force and, as far as the design allows, at rest for the present error
(least squares on [(I - A) x = B e, C x = u/gain - D e], the output rows weighted heavily;
its pseudo-inverse is derived with the controller, beside the loop, so the take-over cycle is
two small vector sums).
The measured angle passes a first-order low-pass ahead of the design (``filter_hz``, 20 Hz
by default, :mod:`controllers.smoothing`; set 0 for a design that filters its own).
Anti-windup by conditional integration, the one rule that fits any design: while a joint's
output is clamped, its part of the state is held whenever its update would move the output
further past the limit (judged by C times the update), and moves freely when it draws the
output back in.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from controllers import lti_design
from controllers.base import Controller, JointState, OptionSpec, ParamSpec, Reference, SignalSpec
from controllers.dob import D_HAT, DOB_PARAMS, WithDisturbanceObserver
from controllers.smoothing import smoothing_gains, smoothing_param

OUTPUT_WEIGHT = 1e3  # of the output-matching rows in the bumpless least-squares fit


class LTI(Controller):
    """Discrete LTI state-space controller per joint, loaded from matrices (e.g. a mu-synthesis design)."""

    name = "lti"
    options = (OptionSpec("design", "the design as a map {joints: {name: {A, B, C, D, dt, input, method}}}; "
                                    "pneumactl reads it from a .toml or .npz file (see docs/controllers.md)",
                          required=True),)
    params = (ParamSpec("gain", "-", 0.0, 10.0, (1.0, 1.0), "scale on the design's output"),
              smoothing_param("filter_hz", "the measured angle, ahead of the design (0 if it filters its own)"))
    internals = (SignalSpec("state_norm", "-", "Euclidean norm of the joint's controller state x"),)

    def check_options(self, options):
        return lti_design.parse(options["design"], self.context.joint_names, self.context.dt)

    def derive(self, values):
        designs = self.chosen
        rows, start = [], 0
        for d in designs:
            rows.append(np.arange(start, start + d.order))
            start += d.order
        a, b, c = (block_diag(*(getattr(d, m) for d in designs)) for m in "abc")
        d, gain = np.array([d.d for d in designs]), np.array(values["gain"])
        # [x(k+1); v(k)] = M [x(k); e(k)], one product per cycle (the cost goal)
        m = np.block([[a, b], [gain[:, None] * c, np.diag(gain * d)]])
        return {"a": a, "b": b, "c": c, "d": d, "gain": gain, "rows": rows, "m": m, "nx": start,
                "smooth": smoothing_gains(values["filter_hz"], self.context.dt),
                "takeover": [_takeover(a, b, c, j, r) for j, r in enumerate(rows)]}

    def __init__(self, context, **values):
        super().__init__(context, **values)
        self._z = np.zeros(self.k["nx"] + context.n)  # [x; e]: the state, then this cycle's error
        self._taking_over: list[float] | None = None
        self._q = [0.0] * context.n  # filtered angle [rad]

    def reset(self, state: JointState, last_output) -> None:
        self._taking_over = [float(u) for u in last_output]
        self._q = [float(q) for q in state.angles]

    def step(self, state: JointState, reference: Reference) -> list[float]:
        k, z, nx = self.k, self._z, self.k["nx"]
        q, smooth = self._q, k["smooth"]
        for j, (a, measured) in enumerate(zip(smooth, state.angles)):
            q[j] += a * (measured - q[j])
        e = [r - qj for r, qj in zip(reference.angles, q)]
        if self._taking_over is not None:
            z[:nx] = self._state_for(np.array(e), self._taking_over)
            self._taking_over = None
        z[nx:] = e
        after = k["m"] @ z
        out = []
        for j, (v, lo, hi) in enumerate(zip(after[nx:].tolist(), self.u_lo, self.u_hi)):
            if v < lo or v > hi:  # anti-windup: a clamped joint's state moves only to draw v back in
                rows = k["rows"][j]
                drift = float(k["m"][nx + j, rows] @ (after[rows] - z[rows]))  # the move's effect on v
                if (drift > 0.0) == (v > hi):
                    after[rows] = z[rows]
                v = lo if v < lo else hi
            out.append(v)
        z[:nx] = after[:nx]
        return out

    def internal_signals(self) -> list[list[float]]:
        return [[float(np.linalg.norm(self._z[rows])) for rows in self.k["rows"]]]

    def _state_for(self, e: np.ndarray, output: list[float]) -> np.ndarray:
        """The state that gives ``output`` now, at rest for the error e if the design allows."""
        k = self.k
        x = np.zeros(k["a"].shape[0])
        for j, (rows, (per_error, per_output)) in enumerate(zip(k["rows"], k["takeover"])):
            if len(rows) and k["gain"][j] != 0.0:
                x[rows] = per_error * e[j] + per_output * (output[j] / k["gain"][j] - k["d"][j] * e[j])
        return x


def _takeover(a: np.ndarray, b: np.ndarray, c: np.ndarray, j: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint j's bumpless state as x = per_error e + per_output (u/gain - D e): the columns of
    the pseudo-inverse of [[I - A], [w C]] that multiply the right-hand side [B e; w (u/gain - D e)]."""
    n = len(rows)
    lhs = np.vstack([np.eye(n) - a[np.ix_(rows, rows)], OUTPUT_WEIGHT * c[j, rows][None, :]])
    inverse = np.linalg.pinv(lhs)
    return inverse[:, :n] @ b[rows, j], inverse[:, n] * OUTPUT_WEIGHT


class LTIWithDOB(WithDisturbanceObserver):
    """The LTI design with the disturbance observer subtracting the estimated input disturbance."""

    name = "lti_dob"
    inner_class = LTI
    params = LTI.params + DOB_PARAMS
    internals = LTI.internals + (D_HAT,)
    options = LTI.options
