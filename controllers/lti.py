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
Anti-windup: while a joint's output is clamped, its part of the state is held
(conditional integration), the one rule that fits any design.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from controllers import lti_design
from controllers.base import Controller, JointState, OptionSpec, ParamSpec, Reference
from controllers.dob import DOB_PARAMS, WithDisturbanceObserver

OUTPUT_WEIGHT = 1e3  # of the output-matching rows in the bumpless least-squares fit


class LTI(Controller):
    """Discrete LTI state-space controller per joint, loaded from matrices (e.g. a mu-synthesis design)."""

    name = "lti"
    options = (OptionSpec("design", "the design as a map {joints: {name: {A, B, C, D, dt, input, method}}}; "
                                    "pneumactl reads it from a .toml or .npz file (see docs/controllers.md)",
                          required=True),)
    params = (ParamSpec("gain", "-", 0.0, 10.0, (1.0, 1.0), "scale on the design's output"),)

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
                "takeover": [_takeover(a, b, c, j, r) for j, r in enumerate(rows)]}

    def __init__(self, context, **values):
        super().__init__(context, **values)
        self._z = np.zeros(self.k["nx"] + context.n)  # [x; e]: the state, then this cycle's error
        self._taking_over: list[float] | None = None

    def reset(self, state: JointState, last_output) -> None:
        self._taking_over = [float(u) for u in last_output]

    def step(self, state: JointState, reference: Reference) -> list[float]:
        k, z, nx = self.k, self._z, self.k["nx"]
        e = [r - q for r, q in zip(reference.angles, state.angles)]
        if self._taking_over is not None:
            z[:nx] = self._state_for(np.array(e), self._taking_over)
            self._taking_over = None
        z[nx:] = e
        after = k["m"] @ z
        out = []
        for j, (v, lo, hi) in enumerate(zip(after[nx:].tolist(), self.context.u_min, self.context.u_max)):
            if v < lo or v > hi:  # anti-windup: a clamped joint's state is held
                after[k["rows"][j]] = z[k["rows"][j]]
                v = lo if v < lo else hi
            out.append(v)
        z[:nx] = after[:nx]
        return out

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
    options = LTI.options
