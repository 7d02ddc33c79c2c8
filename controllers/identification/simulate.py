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
friction step as the simulator in :mod:`sim_backend.joint_model`: by default [2-45]'s smooth
sign, linearly implicit; ``friction_model="karnopp"``: Karnopp's stick rule), vectorised over
the population: one Python loop over time, numpy over the members.
"""
from __future__ import annotations

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
    k_mdl, J, D, K, _, _, Fs, Fc, vs, c = params.T
    members, steps = torque.shape
    a = np.zeros((members, 2, 2))
    a[:, 0, 1] = 1.0
    a[:, 1, 0] = -K / J
    a[:, 1, 1] = -D / J
    block = np.zeros((members, 3, 3))
    block[:, :2, :2] = a * step
    block[:, 1, 2] = step / J
    e = expm(block)
    p11, p12, p21, p22 = e[:, 0, 0], e[:, 0, 1], e[:, 1, 0], e[:, 1, 1]
    g1, g2 = e[:, 0, 2], e[:, 1, 2]  # response of (y, w) to one N m held over the step
    th, w = np.zeros(members), np.zeros(members)
    out = np.empty((steps, members))
    slope = Fs - Fc
    sharp = beta / vs
    inv_vs, inv_g2 = 1.0 / vs, 1.0 / g2
    tau_all = np.ascontiguousarray((torque + c[:, None]).T)  # a row a step
    if friction_model == "stribeck":
        return _smooth(out, tau_all, (p11, p12, p21, p22, g1, g2), (Fs, Fc, vs), alpha, beta)
    for k in range(steps):
        tau = tau_all[k]
        th_lin = p11 * th + p12 * w + g1 * tau
        w_lin = p21 * th + p22 * w + g2 * tau
        f_slip = (Fc + slope * np.exp(-np.power(np.abs(w) * inv_vs, alpha))) * np.tanh(sharp * w)
        slipping = (w_lin - g2 * f_slip) * w > 0.0  # moving on, the same way
        hold = w_lin * inv_g2  # the torque that would stop it this step
        sticks = ~slipping & (np.abs(hold) <= Fs)
        f = np.where(slipping, f_slip, np.where(sticks, hold, np.copysign(Fs, hold)))
        new_th = np.where(sticks & (w == 0.0), th, th_lin - g1 * f)  # stuck all step: not a hair of motion
        w = np.where(sticks, 0.0, w_lin - g2 * f)
        th = new_th
        out[k] = th
    return out.T


def _smooth(out: np.ndarray, tau_all: np.ndarray, zoh, friction, alpha: float, beta: float) -> np.ndarray:
    """:func:`mechanics` with [2-45]'s smooth sign taken at each step's end velocity, one
    Newton step of backward Euler from the present one, as
    :func:`sim_backend.joint_model.stribeck_step` does for one joint (vectorised)."""
    p11, p12, p21, p22, g1, g2 = zoh
    Fs, Fc, vs = friction
    members = len(g1)
    th, w = np.zeros(members), np.zeros(members)
    slope_s, inv_vs, sharp, floor = Fs - Fc, 1.0 / vs, beta / vs, -0.5 / g2
    for k in range(len(out)):
        tau = tau_all[k]
        th_lin = p11 * th + p12 * w + g1 * tau
        w_lin = p21 * th + p22 * w + g2 * tau
        x = np.abs(w) * inv_vs
        xa = np.power(x, alpha - 1.0)
        ex = np.exp(-xa * x)
        magnitude = Fc + slope_s * ex
        sign = np.tanh(sharp * w)
        slope = magnitude * sharp * (1.0 - sign * sign) - slope_s * ex * alpha * xa * inv_vs * np.abs(sign)
        slope = np.maximum(slope, floor)
        v = (w_lin - g2 * (magnitude * sign - slope * w)) / (1.0 + g2 * slope)
        v = np.where(w_lin > 0.0, np.clip(v, 0.0, np.maximum(w_lin, 0.0)), np.clip(v, np.minimum(w_lin, 0.0), 0.0))
        f = np.where(w_lin != 0.0, (w_lin - v) / np.where(w_lin != 0.0, g2, 1.0), 0.0)
        th = th_lin - g1 * f
        w = v
        out[k] = th
    return out.T


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
