"""One cycle of the daemon's loop on the simulated cylinder arm, but the controller, compiled:
the write of the last command, the plant's steps, the input sweep, the drivers' conversion,
the velocity filter and the supervisor's checks. The fast engine (:mod:`evaluation.fast`)
calls it once a cycle and steps the controller in Python between two calls.

Each part restates its original, the same operations in the same order, so that both give the
same numbers (tests/test_evaluation.py holds the fast engine equal to the daemon's loop):
- write: :meth:`hal.actuation.RigActuation.outputs` (head at bias + V_MV through the regulator
  line [2-29], rod at its bias), :meth:`daemon.loop.safety.Supervisor.clamp` (rig maximum,
  slew per cycle), :meth:`hal.rig.RigIO.volts_for` and the regulator's inverse, the DAC's
  quantisation (:func:`sim_backend.transport.quantise`);
- plant: :meth:`sim_backend.transport.SimTransport._advance` with the compiled step
  (:func:`sim_backend.compiled_plant._advance`);
- sweep: :meth:`sim_backend.transport.SimTransport._sample` (sensor volts, the noise drawn
  beforehand in the same order, the ADC);
- read: :meth:`hal.potentiometer.RDC506.convert` per joint (NaN: a sensor fault),
  :meth:`daemon.loop.cycle.ControlLoop._update_measurement`, and
  :meth:`daemon.loop.safety.Supervisor.check` (faults in a row, joint limits, speed in a row).

Arrays (columns named below): J per joint, C per input channel, O per output channel, G the
globals, K the counters, noise the draws, U in (the last command, then the reference angles it
was computed for), A out (angles then velocities), L the log (a row per cycle: reference,
angles, command, written at the next call).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from sim_backend.compiled_plant import _advance

# J columns: position sensor, command path, limits, state
J_SIG, J_SUP, J_SUPPLY_NOM, J_ANGLE0, J_GAIN, J_ZERO, J_LO, J_HI, J_RLO, J_RHI, J_TLO, J_THI = range(12)
J_OUT_HEAD, J_OUT_ROD, J_BIAS, J_ROD_PA = 12, 13, 14, 15
J_H_SLOPE, J_H_OFFSET, J_H_PMIN, J_H_PMAX, J_R_SLOPE, J_R_OFFSET, J_R_PMIN, J_R_PMAX = range(16, 24)
J_QMIN, J_QMAX, J_WMAX = 24, 25, 26
J_ANGLE, J_VEL, J_PH, J_PR = 27, 28, 29, 30
J_WIDTH = 31
# C columns: what (0 position, 1 first chamber, 2 second, 3 force, 4 supply pressure, 5 constant), joint, offset, slope, ADC
C_WHAT, C_JOINT, C_OFFSET, C_SLOPE, C_LOW, C_HIGH, C_LSB, C_VALUE = range(8)
C_WIDTH = 8
O_LOW, O_HIGH, O_LSB, O_VALUE = range(4)
O_WIDTH = 4
# G: globals
G_PREV_T, G_FILTER_W, G_STEP_S, G_T0, G_SUPPLY_PA, G_P_MAX, G_DP, G_SIGMA, G_CONTACT_F = range(9)
G_REG = 9  # 5 regulator constants of the plant
G_WIDTH = 14
# K: counters; K_LOG: the log's next row (-1: no log)
K_STEPS, K_NOISE, K_BAD_SENSOR, K_BAD_SPEED, K_N_BAD, K_WRITE, K_LOG = range(7)
K_WIDTH = 7
# the cycle's outcome
OK, SENSOR_TRIP, LIMIT_TRIP, SPEED_TRIP = 0, 1, 2, 3


@numba.njit(cache=True, inline="always")
def _clip(x, low, high):
    return low if x < low else high if x > high else x


@numba.njit(cache=True, inline="always")
def _quantise(value, low, high, lsb):
    return low + np.rint((_clip(value, low, high) - low) / lsb) * lsb


@numba.njit(cache=True)
def log_row(J, K, U, L):
    """The last cycle's row of the log: its reference and command (U), its angles."""
    row = K[K_LOG]
    if row < 0 or row >= L.shape[0]:
        return
    n, width = J.shape[0], U.shape[0] - J.shape[0]
    for i in range(n):
        L[row, i] = U[width + i]
        L[row, n + i] = J[i, J_ANGLE]
    for c in range(width):
        L[row, 2 * n + c] = U[c]
    K[K_LOG] = row + 1


@numba.njit(cache=True)
def cycle(now, J, C, O, G, K, noise, coef, buf, state, k, tau, U, A, L):
    """One cycle at ``now``; the outcome (OK or a trip) and, for a trip, the joint (+ 16 x code)."""
    n = J.shape[0]
    # write the last command (the cycle before's), when the loop wrote one; log its cycle
    if K[K_WRITE]:
        log_row(J, K, U, L)
        p_max, dp = G[G_P_MAX], G[G_DP]
        for i in range(n):
            j = J[i]
            v = _clip(j[J_BIAS] + U[i], 0.0, 10.0)
            ph = _clip(j[J_H_SLOPE] * v + j[J_H_OFFSET], j[J_H_PMIN], j[J_H_PMAX])
            pr = j[J_ROD_PA]
            for side in range(2):
                p = ph if side == 0 else pr
                last = j[J_PH] if side == 0 else j[J_PR]
                p = p if p < p_max else p_max
                p = last - dp if p < last - dp else last + dp if p > last + dp else p
                if side == 0:
                    j[J_PH] = p
                else:
                    j[J_PR] = p
            for side in range(2):
                p = j[J_PH] if side == 0 else j[J_PR]
                p = p_max if p > p_max else p
                slope = j[J_H_SLOPE] if side == 0 else j[J_R_SLOPE]
                offset = j[J_H_OFFSET] if side == 0 else j[J_R_OFFSET]
                low = j[J_H_PMIN] if side == 0 else j[J_R_PMIN]
                high = j[J_H_PMAX] if side == 0 else j[J_R_PMAX]
                volts = _clip((_clip(p, low, high) - offset) / slope, 0.0, 10.0)
                o = O[int(j[J_OUT_HEAD] if side == 0 else j[J_OUT_ROD])]
                o[O_VALUE] = _quantise(volts, o[O_LOW], o[O_HIGH], o[O_LSB])
    # the plant to the present, in whole steps, with the outputs held
    h = G[G_STEP_S]
    due = int((now - G[G_T0]) / h + 1e-6) - K[K_STEPS]
    if due > 0:
        _advance(coef, buf, state, k, O[:, O_VALUE].copy(), tau, G[G_SUPPLY_PA], G[G_REG:G_REG + 5], due)
        K[K_STEPS] += due
    # the input sweep
    sigma = G[G_SIGMA]
    for c in range(C.shape[0]):
        ch = C[c]
        what = int(ch[C_WHAT])
        jj = int(ch[C_JOINT])
        if what == 0:
            v = ch[C_OFFSET] + ch[C_SLOPE] * math.radians(state[jj, 0])
        elif what == 1:
            v = ch[C_OFFSET] + ch[C_SLOPE] * state[jj, 2]
        elif what == 2:
            v = ch[C_OFFSET] + ch[C_SLOPE] * state[jj, 3]
        elif what == 3:
            v = ch[C_OFFSET] + ch[C_SLOPE] * G[G_CONTACT_F]
        elif what == 4:
            v = ch[C_OFFSET] + ch[C_SLOPE] * G[G_SUPPLY_PA]
        else:
            v = ch[C_OFFSET]
        if sigma > 0.0:
            v += 0.0 + noise[K[K_NOISE]] * sigma
            K[K_NOISE] += 1
        ch[C_VALUE] = _quantise(v, ch[C_LOW], ch[C_HIGH], ch[C_LSB])
    # the drivers' conversion and the velocity filter
    dt = now - G[G_PREV_T]
    G[G_PREV_T] = now
    a = -math.expm1(-G[G_FILTER_W] * dt) if dt > 0.0 else 0.0
    inv_dt = 1.0 / dt if dt > 0.0 else 0.0
    fault = -1
    for i in range(n):
        j = J[i]
        volts = C[int(j[J_SIG]), C_VALUE]
        supply = C[int(j[J_SUP]), C_VALUE] if j[J_SUP] >= 0 else j[J_SUPPLY_NOM]
        q = math.nan
        if 0.5 * j[J_SUPPLY_NOM] < supply < 1.5 * j[J_SUPPLY_NOM]:
            ratio = volts / supply
            if j[J_RLO] < ratio < j[J_RHI] and j[J_TLO] <= ratio <= j[J_THI]:
                q = j[J_ANGLE0] + j[J_GAIN] * (ratio - j[J_ZERO])
                if not (j[J_LO] <= q <= j[J_HI]):
                    q = math.nan
        if q == q:
            if dt > 0.0:
                raw = (q - j[J_ANGLE]) * inv_dt
                j[J_VEL] += a * (raw - j[J_VEL])
                j[J_ANGLE] = q
        elif fault < 0:
            fault = i
        A[i] = j[J_ANGLE]
        A[n + i] = j[J_VEL]
    # the supervisor's checks
    if fault >= 0:
        K[K_BAD_SENSOR] += 1
        return SENSOR_TRIP * 16 + fault if K[K_BAD_SENSOR] >= K[K_N_BAD] else OK
    K[K_BAD_SENSOR] = 0
    for i in range(n):
        q = J[i, J_ANGLE]
        if not J[i, J_QMIN] <= q <= J[i, J_QMAX]:
            return LIMIT_TRIP * 16 + i
    for i in range(n):
        if abs(J[i, J_VEL]) > J[i, J_WMAX]:
            K[K_BAD_SPEED] += 1
            return SPEED_TRIP * 16 + i if K[K_BAD_SPEED] >= K[K_N_BAD] else OK
    K[K_BAD_SPEED] = 0
    return OK


@numba.njit(cache=True)
def gauss_pairs(uniforms, first):
    """Python's ``random.gauss`` values from its ``random()`` draws (two a pair: Box-Muller as
    CPython computes it, cos then sin), after ``first`` (a pending value, NaN for none)."""
    pending = 0 if first != first else 1
    out = np.empty(uniforms.shape[0] + pending)
    if pending:
        out[0] = first
    for p in range(uniforms.shape[0] // 2):
        x2pi = uniforms[2 * p] * (2.0 * math.pi)  # CPython: random() * TWOPI
        g2rad = math.sqrt(-2.0 * math.log(1.0 - uniforms[2 * p + 1]))
        out[pending + 2 * p] = math.cos(x2pi) * g2rad
        out[pending + 2 * p + 1] = math.sin(x2pi) * g2rad
    return out
