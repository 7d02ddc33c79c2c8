"""A built-in controller's constants and state, copied after its first step into the arrays of
:mod:`evaluation.twin_steps`, which then step it compiled. Only the built-ins' own classes
(not subclasses, not plugins) are taken; the rest run their Python step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controllers.dob import WithDisturbanceObserver
from controllers.lti import LTI, LTIWithDOB
from controllers.pid import PID
from controllers.sac import SAC
from controllers.smc import SMC, SMCWithDOB
from evaluation import twin_steps as T

KINDS = {PID: T.PID, SMC: T.SMC, SAC: T.SAC, LTI: T.LTI}
OBSERVED = {SMCWithDOB: SMC, LTIWithDOB: LTI}


@dataclass
class Twin:
    """The arrays :func:`evaluation.twin_steps.step` reads and writes (its docstring)."""

    kind: int
    dob: bool
    P: np.ndarray
    S: np.ndarray
    E: np.ndarray
    X: np.ndarray
    R: np.ndarray
    DP: np.ndarray
    DS: np.ndarray
    DR: np.ndarray
    M: np.ndarray
    Z: np.ndarray
    KS: np.ndarray
    SC: np.ndarray
    LIM: np.ndarray
    dt: float

    def arrays(self) -> tuple:
        """The arguments of twin_steps.step from P to SC, then dt."""
        return (self.P, self.S, self.E, self.X, self.R, self.DP, self.DS, self.DR, self.M, self.Z, self.KS,
                self.SC, self.dt)


def placeholder(n: int) -> Twin:
    """A twin of the right types and no content: what compiles the twins' loop ahead of use."""
    empty = np.zeros((n, 1))
    return Twin(T.PID, False, empty, empty, empty, empty, empty, empty, empty, empty, np.zeros((1, 1)), np.zeros(1),
                np.zeros(3, dtype=np.int64), np.zeros((3 + n, 3)), np.zeros((n, 2)), 0.001)


def supported(controller) -> bool:
    """Whether ``controller`` is a built-in the twins restate."""
    return type(controller) in KINDS or type(controller) in OBSERVED


def after_first_step(controller) -> Twin | None:
    """The twin of ``controller`` as its last step left it; None where its step is not restated
    or a take-over is still pending (its next step must be the Python one)."""
    kind_class = OBSERVED.get(type(controller), type(controller))
    if kind_class not in KINDS:
        return None
    dob = isinstance(controller, WithDisturbanceObserver)
    inner = controller.inner if dob else controller
    if (dob and controller._taking_over is not None) or _pending(inner):
        return None
    n, ctx = controller.context.n, controller.context
    empty = np.zeros((n, 1))
    P, S, E, X, R, M, Z = _inner(inner, KINDS[kind_class])
    nx = M.shape[0] - n if kind_class is LTI else 0
    KS = np.zeros(3, dtype=np.int64)
    KS[T.KS_NX] = nx
    if kind_class in (SMC, SAC):
        KS[T.KS_EST] = inner.k.estimator._k
    DP, DS, DR = (empty, empty, empty)
    if dob:
        DP, DS, DR = _observer(controller.k)
        KS[T.KS_DOB] = controller.k._k
    SC = np.zeros((3 + n, max(3, nx + n, n)))
    LIM = np.array([ctx.u_min, ctx.u_max], dtype=float).T.copy()
    if list(controller.u_lo) != list(ctx.u_min) or list(controller.u_hi) != list(ctx.u_max):
        return None  # a range not the rig's: not restated
    return Twin(KINDS[kind_class], dob, P, S, E, X, R, DP, DS, DR, M, Z, KS, SC, LIM, float(ctx.dt))


def _pending(c) -> bool:
    """Whether the next step of ``c`` takes over (its first after a switch)."""
    if isinstance(c, PID):
        return bool(c._taking_over)
    if isinstance(c, SAC):
        return c._first is not None
    return c._taking_over is not None


def _inner(c, kind: int):
    """P, S, E, X, R, M, Z of the controller itself."""
    n = c.context.n
    E, X, R = np.zeros((n, 1)), np.zeros((n, 1)), np.zeros((n, 1))
    M, Z = np.zeros((1, 1)), np.zeros(1)
    if kind == T.PID:
        g = c.k
        P = np.array([g.kp, g.ki, g.ad, g.bd, g.kt, g.smooth], dtype=float).T.copy()
        S = np.array([c._q, c._i, c._i_used, c._d, c._e_prev], dtype=float).T.copy()
    elif kind == T.SMC:
        P = np.array(c._joints, dtype=float)
        S = np.array([c._z], dtype=float).T.copy()
        E, X, R = _estimator(c.k.estimator)
    elif kind == T.SAC:
        k = c.k
        P = np.array([k.am, k.s1, k.s2, k.gi_e, k.gi_x, k.gp, k.switch, k.boundary, k.decay, k.deadzone, k.aw, k.af,
                      k.kf], dtype=float).T.copy()
        S = np.array([[*c._xm[j], c._xf[j], *c._ki[j], c._offset[j], c._u_mean[j], c._e_y[j]] for j in range(n)])
        E, X, R = _estimator(k.estimator)
    else:
        k = c.k
        P = np.array([[r[0] if len(r) else 0, len(r), a] for r, a in zip(k["rows"], k["smooth"])], dtype=float)
        if any(len(r) and list(r) != list(range(int(r[0]), int(r[0]) + len(r))) for r in k["rows"]):
            raise ValueError("the LTI design's rows are not contiguous")
        S = np.array([c._q], dtype=float).T.copy()
        M, Z = np.ascontiguousarray(k["m"], dtype=float), c._z.copy()
    return P, S, E, X, R, M, Z


def _estimator(est):
    """E, X, R of a DelayedStateEstimator."""
    E = np.array([[*coef[:9], *coef[9:12], *gain, delay, u_off] for coef, gain, delay, u_off
                  in zip(est._coef, est._gain, est.delay, est.u_off)], dtype=float)
    X = np.array([[*x, *dx] for x, dx in zip(est.x, est.dx)], dtype=float)
    R = np.zeros((est.n, max(est.delay) + 1))
    for j, buf in enumerate(est._buf):
        R[j, :len(buf)] = buf
    return E, X, R


def _observer(obs):
    """DP, DS, DR of a DisturbanceObserver."""
    DP = np.array([[*f.coef, off, lim, a, delay] for f, off, lim, a, delay
                   in zip(obs._filters, obs.u_off, obs.limit, obs._smooth, obs.delay)], dtype=float)
    DS = np.array([[f.z0, f.z1, f.z2, raw, d] for f, raw, d in zip(obs._filters, obs._raw, obs.d_hat)], dtype=float)
    DR = np.zeros((obs.n, max(obs.delay) + 1))
    for j, buf in enumerate(obs._buf):
        DR[j, :len(buf)] = buf
    return DP, DS, DR
