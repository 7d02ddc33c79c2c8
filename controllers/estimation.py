"""State estimation for the model-based controllers: an observer of the delayed plant and a
Smith predictor in state form, for all joints at once.

The plant of rig-facts §1 [2-43] has x = [th, th', th''] and an input dead time T_dly; only th
is measured. Per joint:

* a steady-state Kalman filter on the delayed plant, augmented with a constant input
  disturbance d [V] so the spring, bias and friction offsets do not bias th' and th'':
  x(k+1) = Phi x(k) + Gamma (u(k-N) + u_off + d),  d(k+1) = d(k);
* a Smith predictor [Smith 1957] in state form: dx(k+1) = Phi dx(k) + Gamma (u(k) - u(k-N)),
  the part of the state the last N outputs have yet to show. The measured angle with the
  observer's rates, plus dx, is the state T_dly ahead, so a controller designed for the delay-free model can act on it.

Phi, Gamma: exact zero-order hold of (A, B) at the loop period; N = round(T_dly / dt).
Units: rad, rad/s, rad/s^2, V.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.linalg import block_diag, expm, solve_discrete_are

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
    """Predicted states [th, th', th''] per joint, from measured angles and the outputs sent."""

    def __init__(self, models: Sequence[NominalJoint], dt: float, angle_noise_rad: Sequence[float],
                 disturbance_rate_v_s: Sequence[float]):
        """``angle_noise_rad`` and ``disturbance_rate_v_s`` per joint set the Kalman weights:
        the larger their ratio, the slower and quieter the estimate."""
        n = len(models)
        self.n = n
        phis, gammas, augmented, aug_in, gains = [], [], [], [], []
        self.models = models
        self.delay = np.array([m.delay_steps(dt) for m in models])
        self.u_off = np.array([m.input_offset for m in models])
        for m, noise, drift in zip(models, angle_noise_rad, disturbance_rate_v_s):
            a, b = m.state_space()
            phi, gamma = zoh(a, b, dt)
            phis.append(phi)
            gammas.append(gamma)
            f = np.block([[phi, gamma], [np.zeros((1, 3)), np.ones((1, 1))]])
            c = np.array([[1.0, 0.0, 0.0, 0.0]])
            q = np.diag([0.0, 0.0, 0.0, (drift * dt) ** 2])
            p = solve_discrete_are(f.T, c.T, q, np.array([[noise ** 2]]))
            gains.append(p @ c.T / (c @ p @ c.T + noise ** 2))
            augmented.append(f)
            aug_in.append(np.vstack([gamma, [[0.0]]]))
        self._f = block_diag(*augmented)
        self._g = block_diag(*aug_in)
        self._m = block_diag(*gains)
        self._phi = block_diag(*phis)
        self._gamma = block_diag(*gammas)
        self._theta_rows = np.arange(n) * 4
        self._state_rows = (np.arange(n)[:, None] * 4 + np.arange(3)).ravel()
        self._cols = np.arange(n)
        self._buf = np.zeros((int(self.delay.max()) + 1, n))
        self._k = 0
        self.x = np.zeros(4 * n)  # [th, th', th'', d] per joint, of the delayed plant
        self.dx = np.zeros(3 * n)  # Smith prediction

    def reset(self, angles: Sequence[float], last_output: Sequence[float]) -> None:
        """At rest at the measured angles with the output in force for the last T_dly."""
        u = np.asarray(last_output, dtype=float)
        th = np.asarray(angles, dtype=float)
        self.x[:] = 0.0
        self.x[self._theta_rows] = th
        self.x[self._theta_rows + 3] = [m.static_volts(q, 0.0, 0.0) - v for m, q, v in zip(self.models, th, u)]
        self.dx[:] = 0.0
        self._buf[:] = u
        self._k = 0

    def estimate(self, angles: Sequence[float]) -> np.ndarray:
        """Correct with this cycle's angles; the predicted states, shape (n, 3)."""
        measured = np.asarray(angles, dtype=float)
        self.x += self._m @ (measured - self.x[self._theta_rows])
        state = self.x[self._state_rows]
        state[0::3] = measured  # the angle is measured: only the rates come from the observer
        return (state + self.dx).reshape(self.n, 3)

    @property
    def disturbance(self) -> np.ndarray:
        """Estimated constant input disturbance per joint [V] (friction, model error)."""
        return self.x[self._theta_rows + 3]

    def advance(self, u: Sequence[float]) -> None:
        """Time update with the outputs sent this cycle [V]."""
        u = np.asarray(u, dtype=float)
        size = len(self._buf)
        self._buf[self._k % size] = u
        delayed = self._buf[(self._k - self.delay) % size, self._cols]
        self.x = self._f @ self.x + self._g @ (delayed + self.u_off)
        self.dx = self._phi @ self.dx + self._gamma @ (u - delayed)
        self._k += 1

    def replace_last(self, u: Sequence[float]) -> None:
        """The outputs of the last :meth:`advance` were not applied, ``u`` was (a shadow run):
        put u in their place. The observer's update used older outputs only, so just the
        buffer and the Smith term, which is linear in the newest output, change."""
        u = np.asarray(u, dtype=float)
        size = len(self._buf)
        last = (self._k - 1) % size
        self.dx += self._gamma @ (u - self._buf[last])
        self._buf[last] = u

    @classmethod
    def from_params(cls, models, dt: float, values) -> "DelayedStateEstimator":
        return cls(models, dt, values["est_noise"], values["est_drift"])


ESTIMATOR_PARAMS = (
    ParamSpec("est_noise", "rad", 1e-6, 1.0, (1e-2, 1e-2),
              "estimator's angle noise: larger is a slower, quieter state estimate"),
    ParamSpec("est_drift", "V/s", 1e-3, 1e3, (0.5, 0.5), "estimator's allowance for the input disturbance to drift"),
)
