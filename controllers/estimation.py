"""State estimation for the model-based controllers: an observer of the delayed plant and a
Smith predictor in state form, for all joints at once.

The plant of rig-facts §1 [2-43] has x = [th, th', th''] and an input dead time T_dly; only th
is measured. Per joint:

* a steady-state Kalman filter on the delayed plant, augmented with a constant input
  disturbance d [V] so the spring, bias and friction offsets do not bias th' and th'':
  x(k+1) = Phi x(k) + Gamma (u(k-N) + u_off + d),  d(k+1) = d(k);
* a Smith predictor [Smith 1957] in state form: dx(k+1) = Phi dx(k) + Gamma (u(k) - u(k-N)),
  the part of the state the last N outputs have yet to show. The observer's state plus dx is
  the state T_dly ahead, so a controller designed for the delay-free model can act on it.
  The angle too is the observer's, not the raw measurement: fed the raw angle, SMC's output
  moved 2000 V/s at rest on the rig's 0.03 deg of sensor noise; the observer's angle cut
  that to a few V/s. ``est_noise`` (3 mrad by default, about 5x the simulated sensor's)
  trades that smoothing against how fast the estimate follows a sudden push (at 10 mrad a
  joint released from a push overshot by twice as much).

Phi, Gamma: exact zero-order hold of (A, B) at the loop period; N = round(T_dly / dt).
Units: rad, rad/s, rad/s^2, V.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from controllers.base import ParamSpec
from controllers.nominal import NominalJoint


def zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation (Phi, Gamma) of x' = A x + B u with u held over dt."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n], block[:n, n:] = a, b
    e = expm(block * dt)
    return e[:n, :n], e[:n, n:]


class DelayedStateEstimator:
    """Predicted states [th, th', th''] per joint, from measured angles and the outputs sent.

    The design (ZOH, steady-state Kalman gain) uses numpy and scipy once; the per-cycle
    updates are plain float arithmetic per joint, which at these sizes (three states) costs a
    fraction of numpy's per-call overhead."""

    def __init__(self, models: Sequence[NominalJoint], dt: float, angle_noise_rad: Sequence[float],
                 disturbance_rate_v_s: Sequence[float]):
        """``angle_noise_rad`` and ``disturbance_rate_v_s`` per joint set the Kalman weights:
        the larger their ratio, the slower and quieter the estimate."""
        self.n = len(models)
        self.models = models
        self.delay = [m.delay_steps(dt) for m in models]
        self.u_off = [m.input_offset for m in models]
        self._phi, self._gamma, self._gain = [], [], []
        for m, noise, drift in zip(models, angle_noise_rad, disturbance_rate_v_s):
            a, b = m.state_space()
            phi, gamma = zoh(a, b, dt)
            f = np.block([[phi, gamma], [np.zeros((1, 3)), np.ones((1, 1))]])
            c = np.array([[1.0, 0.0, 0.0, 0.0]])
            q = np.diag([0.0, 0.0, 0.0, (drift * dt) ** 2])
            p = solve_discrete_are(f.T, c.T, q, np.array([[noise ** 2]]))
            self._phi.append(tuple(tuple(float(v) for v in row) for row in phi))
            self._gamma.append(tuple(float(v) for v in gamma.ravel()))
            self._gain.append(tuple(float(v) for v in (p @ c.T / (c @ p @ c.T + noise ** 2)).ravel()))
        self._coef = [(*(v for row in p for v in row), *g) for p, g in zip(self._phi, self._gamma)]
        self._buf = [[0.0] * (d + 1) for d in self.delay]  # outputs sent, a ring per joint
        self._k = 0
        self.x = [[0.0] * 4 for _ in range(self.n)]  # [th, th', th'', d] per joint, of the delayed plant
        self.dx = [[0.0] * 3 for _ in range(self.n)]  # Smith prediction
        self._rows = self._per_joint()

    def reset(self, angles: Sequence[float], last_output: Sequence[float]) -> None:
        """At rest at the measured angles with the output in force for the last T_dly."""
        for j, (m, q, u) in enumerate(zip(self.models, angles, last_output)):
            self.x[j] = [float(q), 0.0, 0.0, m.static_volts(q, 0.0, 0.0) - u]
            self.dx[j] = [0.0, 0.0, 0.0]
            self._buf[j] = [float(u)] * (self.delay[j] + 1)
        self._k = 0
        self._rows = self._per_joint()

    def estimate(self, angles: Sequence[float]) -> list[list[float]]:
        """Correct with this cycle's angles; the predicted [th, th', th''] per joint."""
        out = []
        for j in range(self.n):
            x, dx, m = self.x[j], self.dx[j], self._gain[j]
            q = angles[j]
            innovation = q - x[0]
            x[0] += m[0] * innovation
            x[1] += m[1] * innovation
            x[2] += m[2] * innovation
            x[3] += m[3] * innovation
            # the observer's angle, not the raw one: the controllers' high gains on th (SMC's
            # sigma, u_eq) would carry the sensor noise to the output (docs/controllers.md)
            out.append([x[0] + dx[0], x[1] + dx[1], x[2] + dx[2]])
        return out

    def advance(self, u: Sequence[float]) -> None:
        """Time update with the outputs sent this cycle [V]."""
        k = self._k
        for j, (buf, delay, u_off, x, dx, coef) in enumerate(self._rows):
            size = len(buf)
            buf[k % size] = uj = float(u[j])
            delayed = buf[(k - delay) % size]
            p00, p01, p02, p10, p11, p12, p20, p21, p22, g0, g1, g2 = coef
            drive = delayed + u_off + x[3]
            x0, x1, x2 = x[0], x[1], x[2]
            x[0] = p00 * x0 + p01 * x1 + p02 * x2 + g0 * drive
            x[1] = p10 * x0 + p11 * x1 + p12 * x2 + g1 * drive
            x[2] = p20 * x0 + p21 * x1 + p22 * x2 + g2 * drive
            fresh = uj - delayed
            d0, d1, d2 = dx
            dx[0] = p00 * d0 + p01 * d1 + p02 * d2 + g0 * fresh
            dx[1] = p10 * d0 + p11 * d1 + p12 * d2 + g1 * fresh
            dx[2] = p20 * d0 + p21 * d1 + p22 * d2 + g2 * fresh
        self._k = k + 1

    def _per_joint(self) -> tuple[tuple, ...]:
        """Per joint what :meth:`advance` reads: its ring, delay, offset, states and (Phi, Gamma)
        as twelve plain floats (the lists themselves: made again when reset replaces them)."""
        return tuple((self._buf[j], self.delay[j], self.u_off[j], self.x[j], self.dx[j], self._coef[j]) for j in range(self.n))

    def replace_last(self, u: Sequence[float]) -> None:
        """The outputs of the last :meth:`advance` were not applied, ``u`` was (a shadow run):
        put u in their place. The observer's update used older outputs only, so just the
        buffer and the Smith term, which is linear in the newest output, change."""
        for j in range(self.n):
            buf = self._buf[j]
            last = (self._k - 1) % len(buf)
            change = float(u[j]) - buf[last]
            buf[last] += change
            g, dx = self._gamma[j], self.dx[j]
            dx[0] += g[0] * change
            dx[1] += g[1] * change
            dx[2] += g[2] * change

    @classmethod
    def from_params(cls, models, dt: float, values) -> "DelayedStateEstimator":
        return cls(models, dt, values["est_noise"], values["est_drift"])


ESTIMATOR_PARAMS = (
    ParamSpec("est_noise", "rad", 1e-6, 1.0, (3e-3, 3e-3),
              "estimator's angle noise: larger is a slower, quieter state estimate"),
    ParamSpec("est_drift", "V/s", 1e-3, 1e3, (0.5, 0.5), "estimator's allowance for the input disturbance to drift"),
)
