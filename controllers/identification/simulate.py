"""The joint model simulated for a whole population of parameter sets at once: what the
differential-evolution fit evaluates, one generation a call.

Model (rig-facts §1 [2-36..2-39, 2-45]), in the model's own units (deg; see :mod:`hal.identified`),
as deviations from the operating point where the experiment started at rest:

    T(t) = K_mdl L (A_H dP_H(t) - A_L dP_L(t)),   T_ep dP_i' = dP_set,i(t - T_dly) - dP_i     [N m, Pa]
    J y'' + D y' + K y = T(t) + c - tau_s(y')                                                 [deg]
    tau_s(w) = (Fc + (Fs - Fc) exp(-(|w|/vs)^alpha)) tanh(beta w / vs)                        [2-45]

``c`` [N m] is the torque static friction held at the start (the operating point is a rest
inside the friction band, so its value is unknown and fitted). The pressure path is linear,
so it is filtered at the recording's rate (1 ms) for every member at once; the mechanics are
stepped at a coarser ``step`` [s] (exact zero-order hold of the 2x2 linear part, the same
friction step as the simulator in :mod:`hal.joint_model`: by default [2-45]'s smooth
sign, linearly implicit; ``friction_model="karnopp"``: Karnopp's stick rule), member by member
in a loop compiled by numba.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm
from scipy.signal import lfilter

# the fitted parameters, in this order in every parameter array (then the nuisance c)
FITTED = ("K_mdl", "J", "D", "K", "T_ep", "T_dly", "Fs", "Fc", "vs")
NUISANCE = ("c",)


def delayed_lagged(q: np.ndarray, dt: float, t_ep: np.ndarray, t_dly: np.ndarray) -> np.ndarray:
    """q [any unit] at period dt [s], delayed by T_dly and through the lag 1/(T_ep s + 1), per
    member: shape (members, samples). The delay's fraction of a period interpolates between
    the two samples it falls between; the lag is exact for a held input."""
    out = np.empty((len(t_ep), len(q)))
    padded = np.concatenate([np.zeros(1), q])
    for i, (tau, delay) in enumerate(zip(t_ep, t_dly)):
        n = int(delay / dt)
        frac = delay / dt - n
        shifted = np.zeros_like(q)
        if n < len(q):
            now = padded[1:len(q) - n + 1]  # q[k - n]
            before = padded[:len(q) - n]  # q[k - n - 1]
            shifted[n:] = (1.0 - frac) * now + frac * before
        a = np.exp(-dt / tau)
        out[i] = lfilter([0.0, 1.0 - a], [1.0, -a], shifted)
    return out


def mechanics(params: np.ndarray, torque: np.ndarray, step: float, alpha: float, beta: float,
              friction_model: str = "stribeck") -> np.ndarray:
    """Joint angle deviation y [deg] at the end of each step, for per-member torque [N m] of
    shape (members, steps) held over each step. ``params`` columns follow FITTED + NUISANCE."""
    if friction_model not in ("stribeck", "karnopp"):
        raise ValueError(f"friction_model must be 'stribeck' or 'karnopp', not {friction_model!r}")
    _, J, D, K, _, _, Fs, Fc, vs, c = np.asarray(params, dtype=float).T
    members, steps = torque.shape
    a = np.zeros((members, 2, 2))
    a[:, 0, 1] = 1.0
    a[:, 1, 0] = -K / J
    a[:, 1, 1] = -D / J
    block = np.zeros((members, 3, 3))
    block[:, :2, :2] = a * step
    block[:, 1, 2] = step / J
    e = expm(block)
    # per member: the 2x2 transition, then the response of (y, w) to one N m held over the step
    coefficients = np.ascontiguousarray(np.column_stack([e[:, 0, 0], e[:, 0, 1], e[:, 1, 0], e[:, 1, 1],
                                                         e[:, 0, 2], e[:, 1, 2], Fs, Fc, vs]))
    out = np.empty((members, steps))
    _stepper()(coefficients, np.ascontiguousarray(torque + c[:, None], dtype=float), float(alpha), float(beta),
               friction_model == "stribeck", out)
    return out


def _step_members(coefficients, torque, alpha, beta, smooth, out):  # pragma: no cover (runs compiled)
    """The mechanics' time loop for every member: exact zero-order hold of the linear part and
    the friction held over the step, as :mod:`hal.joint_model` steps one joint:
    ``smooth``, [2-45]'s smooth sign at the step's end velocity (one Newton step of backward
    Euler from the present one, as ``stribeck_step``); else Karnopp's stick rule. Plain loops
    over floats, for numba to compile: a member's step is a dozen arithmetic operations,
    which numpy's per-call cost, over the population, made ~25 times dearer."""
    members, steps = torque.shape
    for m in range(members):
        p11, p12, p21, p22, g1, g2, fs, fc, vs = coefficients[m]
        slope_s, sharp, inv_vs, inv_g2, floor = fs - fc, beta / vs, 1.0 / vs, 1.0 / g2, -0.5 / g2
        th = 0.0
        w = 0.0
        for k in range(steps):
            tau = torque[m, k]
            th_lin = p11 * th + p12 * w + g1 * tau
            w_lin = p21 * th + p22 * w + g2 * tau
            if smooth:
                x = abs(w) * inv_vs
                xa = x ** (alpha - 1.0)
                ex = math.exp(-xa * x)
                magnitude = fc + slope_s * ex
                sign = math.tanh(sharp * w)
                slope = max(magnitude * sharp * (1.0 - sign * sign) - slope_s * ex * alpha * xa * inv_vs * abs(sign),
                            floor)
                v = (w_lin - g2 * (magnitude * sign - slope * w)) / (1.0 + g2 * slope)
                if w_lin > 0.0:  # friction slows the joint, never turns it round within a step
                    v = min(max(v, 0.0), w_lin)
                else:
                    v = min(max(v, w_lin), 0.0)
                f = (w_lin - v) * inv_g2 if w_lin != 0.0 else 0.0
                th = th_lin - g1 * f
                w = v
            else:
                f_slip = (fc + slope_s * math.exp(-(abs(w) * inv_vs) ** alpha)) * math.tanh(sharp * w)
                slipping = (w_lin - g2 * f_slip) * w > 0.0  # moving on, the same way
                hold = w_lin * inv_g2  # the torque that would stop it this step
                sticks = not slipping and abs(hold) <= fs
                if slipping:
                    f = f_slip
                elif sticks:
                    f = hold
                else:
                    f = math.copysign(fs, hold)
                if not (sticks and w == 0.0):  # stuck all step: not a hair of motion
                    th = th_lin - g1 * f
                w = 0.0 if sticks else w_lin - g2 * f
            out[m, k] = th


_compiled = None


def _stepper():
    """:func:`_step_members` compiled by numba, once a process (about a second), on first use:
    importing this module (the client's identify does, for FITTED) stays cheap."""
    global _compiled
    if _compiled is None:
        import numba

        _compiled = numba.njit(cache=False)(_step_members)
    return _compiled


def samples_per_step(step: float, dt: float) -> int:
    """How many recorded samples (period dt [s]) one mechanics step of ``step`` [s] holds: the
    simulation's grid, which every comparison with the data (y[m::m]) must share."""
    return max(int(round(step / dt)), 1)


def held_torque(params: np.ndarray, lever: np.ndarray, dt: float, step: float) -> np.ndarray:
    """Torque [N m] per member held over each mechanics step (the mean of the step's
    samples), shape (members, steps): K_mdl times the lever delayed and lagged."""
    m = samples_per_step(step, dt)
    torque = params[:, 0:1] * delayed_lagged(lever, dt, params[:, 4], params[:, 5])
    usable = (torque.shape[1] // m) * m
    return torque[:, :usable].reshape(len(params), -1, m).mean(axis=2)


def simulate(params: np.ndarray, lever: np.ndarray, dt: float, step: float, alpha: float,
             beta: float) -> np.ndarray:
    """Angle deviation [deg] on the step grid (every ``step / dt``-th sample from the first
    step on) for each row of ``params``; ``lever`` = L (A_H dP_set,H - A_L dP_set,L) [N m per
    unit K_mdl] at the recording's period dt [s]."""
    params = np.atleast_2d(params)
    m = samples_per_step(step, dt)
    return mechanics(params, held_torque(params, lever, dt, step), m * dt, alpha, beta)


def simulate_experiments(params: list[np.ndarray], levers: list[np.ndarray], dts: list[float], step: float,
                         alpha: float, beta: float) -> list[np.ndarray]:
    """:func:`simulate` for several experiments (``params[i]``'s rows on ``levers[i]`` at
    ``dts[i]``), those with the same mechanics step run as one population: the mechanics'
    loop over time costs per step, nearly whatever the members, so two experiments simulated
    side by side cost the longer one's steps rather than both's. Each member is independent:
    the results are :func:`simulate`'s, experiment by experiment."""
    out: list[np.ndarray | None] = [None] * len(params)
    groups: dict[float, list[int]] = {}
    for i, dt in enumerate(dts):
        groups.setdefault(samples_per_step(step, dt) * dt, []).append(i)
    for held_step, members in groups.items():
        rows = [np.atleast_2d(params[i]) for i in members]
        torques = [held_torque(r, levers[i], dts[i], step) for r, i in zip(rows, members)]
        steps = max(t.shape[1] for t in torques)
        padded = np.concatenate([np.pad(t, ((0, 0), (0, steps - t.shape[1]))) for t in torques])
        angles = mechanics(np.concatenate(rows), padded, held_step, alpha, beta)
        start = 0
        for r, t, i in zip(rows, torques, members):
            out[i] = angles[start:start + len(r), :t.shape[1]]
            start += len(r)
    return out
