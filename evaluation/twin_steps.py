"""The built-in controllers' steps, compiled: what :mod:`evaluation.twin_run` calls a cycle so
that a whole case of a built-in controller runs inside one compiled loop.

Each function restates its original, the same operations in the same order (so both give the
same numbers; tests/test_evaluation.py holds every built-in's case equal to the daemon's loop):
- :func:`estimate`, :func:`advance`: :class:`controllers.estimation.DelayedStateEstimator`;
- :func:`pid`: :meth:`controllers.pid.PID.step` [3-3, 3-4];
- :func:`smc`: :meth:`controllers.smc.SMC.step` [3-84..3-90];
- :func:`sac`: :meth:`controllers.sac.SAC.step` [3-44..3-56];
- :func:`lti`: :meth:`controllers.lti.LTI.step`;
- :func:`dob_estimate`, :func:`dob_sent`: :class:`controllers.dob.DisturbanceObserver`, and
  :func:`step` the wrapper :meth:`controllers.dob.WithDisturbanceObserver.step` around any.
The first step after a switch (the bumpless take-over) stays the Python controller's: its state
after that step is what :mod:`evaluation.twin_state` copies into the arrays below.

Arrays (columns named below), a row per joint: P the controller's constants, S its state,
E and X the estimator's constants and state, R the estimator's ring of outputs sent (its
length is the delay + 1), DP, DS, DR the observer's; LIM the rig's output range [V]; M and Z
the LTI design's block matrix and state [x; e]; KS the counters; SC scratch. Units as the
originals: rad, rad/s, rad/s^2, V.
"""
from __future__ import annotations

import numba
import numpy as np

PID, SMC, SAC, LTI = range(4)
# E (estimator constants): Phi row-major, Gamma, the Kalman gain, the delay [cycles], u_off [V]
E_PHI, E_GAMMA, E_GAIN, E_DELAY, E_UOFF = 0, 9, 12, 16, 17
E_WIDTH = 18
X_WIDTH = 7  # x = [th, th', th'', d], then the Smith prediction dx
# KS: the estimator's and the observer's cycle counters, the LTI design's state size
KS_EST, KS_DOB, KS_NX = range(3)
# P and S per kind
PID_KP, PID_KI, PID_AD, PID_BD, PID_KT, PID_SMOOTH = range(6)
PID_Q, PID_I, PID_I_USED, PID_D, PID_E_PREV = range(5)
SMC_WIDTH = 11  # (S0..S3, SA0..SA2, SB, k, eta, lambda) as SMC._joints; S: z
SAC_AM, SAC_S1, SAC_S2, SAC_GI_E, SAC_GI_X, SAC_GP, SAC_SWITCH, SAC_BOUNDARY, SAC_DECAY, SAC_DEADZONE, \
    SAC_AW, SAC_AF, SAC_KF = range(13)
SAC_XM, SAC_XF, SAC_KI, SAC_OFFSET, SAC_MEAN, SAC_EY = 0, 3, 4, 10, 11, 12
LTI_START, LTI_ORDER, LTI_SMOOTH = range(3)  # S: the filtered angle
# DP: the third-order filter's 11 coefficients, u_off, limit, the fourth pole's gain, delay; DS: z0..z2, raw, d_hat
DP_COEF, DP_UOFF, DP_LIMIT, DP_SMOOTH, DP_DELAY = 0, 11, 12, 13, 14
DS_Z, DS_RAW, DS_DHAT = 0, 3, 4


@numba.njit(cache=True)
def estimate(E, X, angles, x):
    """DelayedStateEstimator.estimate: correct with the angles; the predicted states into x (n x 3)."""
    for j in range(E.shape[0]):
        s = X[j]
        innovation = angles[j] - s[0]
        s[0] += E[j, E_GAIN] * innovation
        s[1] += E[j, E_GAIN + 1] * innovation
        s[2] += E[j, E_GAIN + 2] * innovation
        s[3] += E[j, E_GAIN + 3] * innovation
        x[j, 0] = s[0] + s[4]
        x[j, 1] = s[1] + s[5]
        x[j, 2] = s[2] + s[6]


@numba.njit(cache=True)
def advance(E, X, R, KS, u):
    """DelayedStateEstimator.advance: the time update with the outputs sent."""
    k = KS[KS_EST]
    for j in range(E.shape[0]):
        e, s = E[j], X[j]
        delay = int(e[E_DELAY])
        size = delay + 1
        uj = u[j]
        R[j, k % size] = uj
        delayed = R[j, (k - delay) % size]
        p00, p01, p02, p10, p11, p12, p20, p21, p22 = e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7], e[8]
        g0, g1, g2 = e[E_GAMMA], e[E_GAMMA + 1], e[E_GAMMA + 2]
        drive = delayed + e[E_UOFF] + s[3]
        x0, x1, x2 = s[0], s[1], s[2]
        s[0] = p00 * x0 + p01 * x1 + p02 * x2 + g0 * drive
        s[1] = p10 * x0 + p11 * x1 + p12 * x2 + g1 * drive
        s[2] = p20 * x0 + p21 * x1 + p22 * x2 + g2 * drive
        fresh = uj - delayed
        d0, d1, d2 = s[4], s[5], s[6]
        s[4] = p00 * d0 + p01 * d1 + p02 * d2 + g0 * fresh
        s[5] = p10 * d0 + p11 * d1 + p12 * d2 + g1 * fresh
        s[6] = p20 * d0 + p21 * d1 + p22 * d2 + g2 * fresh
    KS[KS_EST] = k + 1


@numba.njit(cache=True)
def pid(P, S, angles, r, lo, hi, out):
    """PID.step after its first cycle (no take-over)."""
    for j in range(P.shape[0]):
        p, s = P[j], S[j]
        q = s[PID_Q] = s[PID_Q] + p[PID_SMOOTH] * (angles[j] - s[PID_Q])
        e = r[j] - q
        s[PID_D] = p[PID_AD] * s[PID_D] + p[PID_BD] * (e - s[PID_E_PREV])
        s[PID_I_USED] = s[PID_I]
        v = p[PID_KP] * e + s[PID_I] + s[PID_D]
        u = lo[j] if v < lo[j] else hi[j] if v > hi[j] else v  # controllers.base.clamp
        s[PID_I] += p[PID_KI] * e + p[PID_KT] * (u - v)
        s[PID_E_PREV] = e
        out[j] = u


@numba.njit(cache=True)
def smc(P, S, E, X, R, KS, x, dt, angles, r, lo, hi, out):
    """SMC.step after its first cycle."""
    estimate(E, X, angles, x)
    for j in range(P.shape[0]):
        p = P[j]
        s0, s1, s2, s3, sa0, sa1, sa2, sb, k, eta, reach = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], \
            p[9], p[10]
        th, w, acc = x[j, 0], x[j, 1], x[j, 2]
        rj = r[j]
        u_eq = -(sa0 * th + sa1 * w + sa2 * acc + s0 * rj) / sb - E[j, E_UOFF]
        rest = s1 * th + s2 * w + s3 * acc
        sigma = s0 * S[j, 0] + rest
        reaching = -k * sigma / (abs(sigma) + eta) - reach * sigma / sb
        v = u_eq + reaching
        u = lo[j] if v < lo[j] else hi[j] if v > hi[j] else v
        e = rj - th
        if u == v or (u > v) == (s0 * e < 0):
            S[j, 0] += e * dt
        out[j] = u
    advance(E, X, R, KS, out)


@numba.njit(cache=True)
def sac(P, S, E, X, R, KS, x, dt, angles, r, lo, hi, out):
    """SAC.step after its first cycle."""
    estimate(E, X, angles, x)
    for j in range(P.shape[0]):
        p, s = P[j], S[j]
        a = p[SAC_AM]
        rj = r[j]
        s[SAC_XM] = m0 = a * s[SAC_XM] + (1 - a) * rj
        s[SAC_XM + 1] = m1 = a * s[SAC_XM + 1] + (1 - a) * m0
        s[SAC_XM + 2] = m2 = a * s[SAC_XM + 2] + (1 - a) * m1
        e = s[SAC_EY] = m2 - (x[j, 0] + s[SAC_XF])
        ki = SAC_KI
        leak = (p[SAC_S1] * e * e + p[SAC_S2]) * dt
        v = p[SAC_GP] * e * e * e
        v += p[SAC_SWITCH] * e / (abs(e) + p[SAC_BOUNDARY])
        v += s[ki] * e
        v += s[ki + 1] * m0
        v += s[ki + 2] * m1
        v += s[ki + 3] * m2
        v += s[ki + 4] * rj
        v += s[ki + 5] * 1.0
        s[SAC_OFFSET] *= p[SAC_DECAY]
        v += s[SAC_OFFSET]
        u = lo[j] if v < lo[j] else hi[j] if v > hi[j] else v
        out[j] = u
        learn = e if abs(e) > p[SAC_DEADZONE] and (u == v or (u > v) == (e > 0)) else 0.0
        gi_e, gi_x = p[SAC_GI_E], p[SAC_GI_X]
        s[ki] += learn * gi_e * e - leak * s[ki]
        s[ki + 1] += learn * gi_x * m0 - leak * s[ki + 1]
        s[ki + 2] += learn * gi_x * m1 - leak * s[ki + 2]
        s[ki + 3] += learn * gi_x * m2 - leak * s[ki + 3]
        s[ki + 4] += learn * gi_x * rj - leak * s[ki + 4]
        s[ki + 5] += learn * gi_x * 1.0 - leak * s[ki + 5]
    for j in range(P.shape[0]):
        p, s = P[j], S[j]
        uj = out[j]
        s[SAC_MEAN] = p[SAC_AW] * s[SAC_MEAN] + (1 - p[SAC_AW]) * uj
        s[SAC_XF] = p[SAC_AF] * s[SAC_XF] + (1 - p[SAC_AF]) * p[SAC_KF] * (uj - s[SAC_MEAN])
    advance(E, X, R, KS, out)


@numba.njit(cache=True)
def lti(P, S, M, Z, KS, after, angles, r, lo, hi, out):
    """LTI.step after its first cycle: [x(k+1); v(k)] = M [x(k); e(k)], then anti-windup."""
    n, nx = P.shape[0], KS[KS_NX]
    for j in range(n):
        S[j, 0] += P[j, LTI_SMOOTH] * (angles[j] - S[j, 0])
    for j in range(n):
        Z[nx + j] = r[j] - S[j, 0]
    after[:] = np.dot(M, Z)  # as numpy's m @ z: the same BLAS product
    for j in range(n):
        v = after[nx + j]
        if v < lo[j] or v > hi[j]:
            start, stop = int(P[j, LTI_START]), int(P[j, LTI_START] + P[j, LTI_ORDER])
            drift = np.dot(M[nx + j, start:stop], after[start:stop] - Z[start:stop])
            if (drift > 0.0) == (v > hi[j]):
                after[start:stop] = Z[start:stop]
            v = lo[j] if v < lo[j] else hi[j]
        out[j] = v
    Z[:nx] = after[:nx]


@numba.njit(cache=True)
def dob_estimate(DP, DS, DR, KS, angles):
    """DisturbanceObserver.estimate: d_hat per joint [V] into DS's column."""
    KS[KS_DOB] = k = KS[KS_DOB] + 1
    for j in range(DP.shape[0]):
        c, s = DP[j], DS[j]
        th, u = angles[j], DR[j, k % (int(c[DP_DELAY]) + 1)]
        b0, b1, b2, b3, c0, c1, c2, c3, a1, a2, a3 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], \
            c[10]
        y = b0 * th + c0 * u + s[0]
        s[0] = b1 * th + c1 * u - a1 * y + s[1]
        s[1] = b2 * th + c2 * u - a2 * y + s[2]
        s[2] = b3 * th + c3 * u - a3 * y
        d = y - c[DP_UOFF]
        d = s[DS_RAW] = s[DS_RAW] + c[DP_SMOOTH] * (d - s[DS_RAW])
        lim = c[DP_LIMIT]
        s[DS_DHAT] = -lim if d < -lim else lim if d > lim else d


@numba.njit(cache=True)
def step(kind, dob, P, S, E, X, R, DP, DS, DR, M, Z, KS, SC, dt, angles, r, LIM, out):
    """One step of the controller ``kind`` (with the observer around it when ``dob``) into out."""
    n = P.shape[0]
    lo, hi = SC[0], SC[1]
    if dob:
        dob_estimate(DP, DS, DR, KS, angles)
        for j in range(n):
            lo[j] = LIM[j, 0] + DS[j, DS_DHAT]
            hi[j] = LIM[j, 1] + DS[j, DS_DHAT]
    else:
        for j in range(n):
            lo[j] = LIM[j, 0]
            hi[j] = LIM[j, 1]
    x = SC[2:2 + n, :3]
    if kind == PID:
        pid(P, S, angles, r, lo, hi, out)
    elif kind == SMC:
        smc(P, S, E, X, R, KS, x, dt, angles, r, lo, hi, out)
    elif kind == SAC:
        sac(P, S, E, X, R, KS, x, dt, angles, r, lo, hi, out)
    else:
        lti(P, S, M, Z, KS, SC[2 + n, :M.shape[0]], angles, r, lo, hi, out)
    if dob:
        k = KS[KS_DOB]
        for j in range(n):
            v = out[j] - DS[j, DS_DHAT]
            u = LIM[j, 0] if v < LIM[j, 0] else LIM[j, 1] if v > LIM[j, 1] else v
            out[j] = u
            DR[j, k % (int(DP[j, DP_DELAY]) + 1)] = u
