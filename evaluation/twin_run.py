"""Cycles of the fast engine with a built-in controller's step compiled too: the loop of
:meth:`evaluation.fast.FastLoop.run` (the cycle, the reference's angles, the step, the output's
check, the command and reference kept for the next write) inside one compiled call, so a case
costs no Python a cycle. The references' angles are sampled beforehand, by the trajectory's
own Python ``sample``, a block of cycles at a time (:meth:`evaluation.fast.FastLoop.run`).

numba caches the compiled loop keyed on this file alone: after editing what it calls
(:mod:`evaluation.twin_steps`, :mod:`evaluation.kernel`, :mod:`sim_backend.compiled_plant`) in
a checkout, delete ``evaluation/__pycache__/twin_run.*.nbi`` (an installed upgrade replaces
every file, so its cache is rebuilt).
"""
from __future__ import annotations

import math

import numba
from evaluation import kernel as K
from evaluation import twin_steps as T

NOT_FINITE = -1  # the step's output was not finite (the loop's check_output)


@numba.njit(cache=True)
def run(kind, dob, now, period, refs, first, logged, J, C, O, G, Kc, noise, coef, buf, state, k, tau, U, A, L,
        P, S, E, X, R, DP, DS, DR, M, Z, KS, SC, dt, LIM, out):
    """``refs.shape[0]`` cycles from ``now`` (a cycle every ``period``); ``first``: this block
    starts a run (its first cycle turns the write on, and the log when ``logged``). The cycles
    done, the outcome (0, a trip's code of :func:`evaluation.kernel.cycle`, or NOT_FINITE) and
    the times of the cycle after the last one done and of that last one."""
    n, width = J.shape[0], U.shape[0] - J.shape[0]
    last = now - period  # not read when no cycle is done
    for i in range(refs.shape[0]):
        outcome = K.cycle(now, J, C, O, G, Kc, noise, coef, buf, state, k, tau, U, A, L)
        if outcome:
            return i, outcome, now, last
        r = refs[i]
        T.step(kind, dob, P, S, E, X, R, DP, DS, DR, M, Z, KS, SC, dt, A[:n], r, LIM, out)
        for c in range(width):
            if not math.isfinite(out[c]):
                return i, NOT_FINITE, now, last
            U[c] = out[c]
        for j in range(n):
            U[width + j] = r[j]
        if first and i == 0:
            Kc[K.K_WRITE] = 1
            if logged:
                Kc[K.K_LOG] = 0
        last = now
        now += period
    return refs.shape[0], 0, now, last

