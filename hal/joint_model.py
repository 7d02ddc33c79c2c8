"""One pneumatic-cylinder joint, simulated exactly at a fixed step (rig-facts §1): the simulator's
plant (sim_backend) and the model that runs beside the arm (controllers.drift) step this one class.

Model [2-30..2-39, 2-45], in the model's own units (deg; see :mod:`hal.identified`):

    T_ep P_i' = P_set,i(t - T_dly) - P_i                    (regulator lag and dead time, per chamber)
    J th'' + D th' + K (th - th_0) = K_mdl L (A_H P_H - A_L P_L) + tau_ext - tau_s(th')
    tau_s(w) = (Fc + (Fs - Fc) exp(-(|w|/vs)^alpha)) tanh(beta w / vs)   [2-45]

The viscous term D th' appears once (the linear model's D); tau_s is the Coulomb/Stribeck part
of [2-45]. With tau_s = 0 the transfer function from the head command V_MV to th is exactly
[2-50]: K_mdl L A_H K_ep / ((J s^2 + D s + K)(T_ep s + 1)) e^{-T_dly s}.

**Discretisation.** The linear part is discretised exactly (zero-order hold, matrix
exponential), including a dead time that is not a whole number of steps (Åström &
Wittenmark's split of the hold interval), so the simulated step response equals the
continuous one at every sample. Friction enters as a torque held over the step, in one of
two models (``friction_model``):

- ``"stribeck"`` (default): [2-45] as identified, the smooth sign. Its tanh is far too stiff
  to integrate explicitly at 1 ms (slope Fs beta / vs against J / h), so the friction is taken
  at the step's end velocity, linearly implicit (one Newton step of backward Euler from the
  present velocity, :func:`stribeck_step`): stable for any slope, and the end velocity is kept
  between 0 and the frictionless one (friction never drives). Under a torque below Fs the
  joint creeps at the speed where the map balances it, as the identified model says.
- ``"karnopp"``: sticking resolved as in Karnopp's model: when the velocity would reach or
  cross zero within a step, the torque needed to stop the joint is computed, and the joint
  sticks exactly if that is within the breakaway torque Fs (stick-slip studies).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from hal.identified import JointParams


def zoh(a: np.ndarray, b: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, integral_0^t e^{A s} ds B), from one matrix exponential."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a * t
    block[:n, n:] = b * t
    e = expm(block)
    return e[:n, :n], e[:n, n:]


def stribeck_step(friction: tuple[float, float, float, float, float], w: float, w_lin: float, g: float) -> float:
    """The friction torque [N m] held over a step of the smooth-sign map [2-45]
    tau_s(w) = (Fc + (Fs - Fc) exp(-(|w|/vs)^alpha)) tanh(beta w / vs), taken at the step's end
    velocity v (v = w_lin - g tau_s(v), g: velocity per N m held over the step) by one Newton
    step from the present velocity ``w``; v kept between 0 and ``w_lin`` (the root is there:
    tau_s is odd and has the sign of its argument). A falling (Stribeck) slope steeper than
    -1 / (2 g) is capped at that, so the step never divides by a small or negative number.
    ``friction``: (Fc, Fs - Fc, vs, alpha, beta) of the joint (:meth:`JointModel.friction_constants`)."""
    if w_lin == 0.0:
        return 0.0
    fc, drop, vs, alpha, beta = friction
    x = abs(w) / vs
    ex = math.exp(-(x ** alpha))
    magnitude = fc + drop * ex
    sign = math.tanh(beta * w / vs)
    f = magnitude * sign
    slope = magnitude * beta / vs * (1.0 - sign * sign)
    if x > 0.0:
        slope -= drop * ex * alpha * x ** (alpha - 1.0) / vs * abs(sign)
    slope = max(slope, -0.5 / g)
    v = (w_lin - g * (f - slope * w)) / (1.0 + g * slope)
    v = min(max(v, 0.0), w_lin) if w_lin > 0.0 else max(min(v, 0.0), w_lin)
    return (w_lin - v) / g


class JointModel:
    """State: angle ``th`` [deg], velocity ``w`` [deg/s], chamber pressures [Pa]."""

    def __init__(self, params: JointParams, dt: float, neutral_deg: float, stops_deg: tuple[float, float],
                 initial_deg: float, initial_pset: tuple[float, float], friction: bool = True,
                 dead_time: bool = True, friction_model: str = "stribeck"):
        self.params = params
        self.dt = dt
        self.friction = friction
        self.karnopp = friction_model == "karnopp"
        self.neutral_deg = neutral_deg
        self.stop_lo, self.stop_hi = stops_deg
        p = params
        self._c = p.K_mdl * p.L  # force -> torque [m]
        self._ah, self._al = p.area_head, p.area_rod

        # x = [T, th, w], T = K_mdl L (A_H P_H - A_L P_L) the pneumatic torque [N m]
        a = np.array([[-1.0 / p.T_ep, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0 / p.J, -p.K / p.J, -p.D / p.J]])
        b_set = np.array([[1.0 / p.T_ep], [0.0], [0.0]])
        b_tau = np.array([[0.0], [0.0], [1.0 / p.J]])
        delay = p.T_dly if dead_time else 0.0
        self.delay_steps = int(math.floor(delay / dt + 1e-9))
        frac = max(delay - self.delay_steps * dt, 0.0)
        if frac < 1e-12:
            frac = 0.0
        phi, _ = zoh(a, b_set, dt)
        e_late, g_late = zoh(a, b_set, dt - frac)  # the part of the step driven by u(k-n)
        _, g_early = zoh(a, b_set, frac)  # the first `frac` seconds, still driven by u(k-n-1)
        g_prev = e_late @ g_early
        _, g_tau = zoh(a, b_tau, dt)
        # Rows for th and w, as plain floats in one tuple (a step unpacks it once): numpy's
        # per-call cost, or an attribute load per coefficient, would dominate at this size.
        self._rows = (*phi[1].tolist(), float(g_late[1, 0]), float(g_prev[1, 0]), float(g_tau[1, 0]),
                      *phi[2].tolist(), float(g_late[2, 0]), float(g_prev[2, 0]), float(g_tau[2, 0]))
        self._spring_nm = p.K * self.neutral_deg  # K th_0 [N m]: the spring's share of the held torque
        self._friction = self.friction_constants(p)
        # Scalar chamber lag with the same split: P(k+1) = a P + b0 u(k-n) + b1 u(k-n-1)
        self._pa = math.exp(-dt / p.T_ep)
        self._pb0 = 1.0 - math.exp(-(dt - frac) / p.T_ep)
        self._pb1 = math.exp(-(dt - frac) / p.T_ep) - self._pa

        size = self.delay_steps + 2
        self._buf_head = [initial_pset[0]] * size
        self._buf_rod = [initial_pset[1]] * size
        self._k = 0
        self.p_head, self.p_rod = initial_pset
        self.th = min(max(initial_deg, self.stop_lo), self.stop_hi)
        self.w = 0.0

    @staticmethod
    def friction_constants(p: JointParams) -> tuple[float, float, float, float, float]:
        """(Fc, Fs - Fc, vs, alpha, beta) of [2-45], as :func:`stribeck_step` takes them."""
        return p.Fc, p.Fs - p.Fc, p.vs, p.alpha, p.beta

    def scale_friction(self, scale: float) -> None:
        """Fs and Fc of [2-45] times ``scale`` from now on (a drift the simulator injects)."""
        self.params = self.params.replace({"Fs": self.params.Fs * scale, "Fc": self.params.Fc * scale})
        self._friction = self.friction_constants(self.params)

    def pneumatic_torque(self, p_head: float, p_rod: float) -> float:
        """K_mdl L (A_H P_H - A_L P_L) [N m]."""
        return self._c * (self._ah * p_head - self._al * p_rod)

    def equilibrium_deg(self, p_head: float, p_rod: float) -> float:
        """Angle [deg] at which the spring balances steady chamber pressures (friction aside)."""
        return self.neutral_deg + self.pneumatic_torque(p_head, p_rod) / self.params.K

    def step(self, pset_head: float, pset_rod: float, tau_ext: float = 0.0) -> None:
        """Advance one step with the regulators asked for these set pressures [Pa] and an
        external torque [N m], both held over the step."""
        buf_head, buf_rod = self._buf_head, self._buf_rod
        size = len(buf_head)
        k = self._k
        buf_head[k % size] = pset_head
        buf_rod[k % size] = pset_rod
        i_now, i_prev = (k - self.delay_steps) % size, (k - self.delay_steps - 1) % size
        h_now, r_now = buf_head[i_now], buf_rod[i_now]
        h_prev, r_prev = buf_head[i_prev], buf_rod[i_prev]
        c, ah, al = self._c, self._ah, self._al  # pneumatic_torque, inline: three calls a step
        t_now = c * (ah * h_now - al * r_now)
        t_prev = c * (ah * h_prev - al * r_prev)
        torque = c * (ah * self.p_head - al * self.p_rod)
        tau = self._spring_nm + tau_ext
        th, w = self.th, self.w
        p10, p11, p12, g0_th, g1_th, gt_th, p20, p21, p22, g0_w, g1_w, gt_w = self._rows
        th_lin = p10 * torque + p11 * th + p12 * w + g0_th * t_now + g1_th * t_prev + gt_th * tau
        w_lin = p20 * torque + p21 * th + p22 * w + g0_w * t_now + g1_w * t_prev + gt_w * tau
        if self.friction and not self.karnopp:
            f = stribeck_step(self._friction, w, w_lin, gt_w)
            th_new, w_new = th_lin - gt_th * f, w_lin - gt_w * f
        elif self.friction:
            f, sticking = self._friction_torque(w, w_lin, gt_w)
            if sticking and w == 0.0:
                th_new, w_new = th, 0.0  # stuck all step: not a hair of motion
            else:
                th_new = th_lin - gt_th * f
                w_new = 0.0 if sticking else w_lin - gt_w * f
        else:
            th_new, w_new = th_lin, w_lin
        if th_new <= self.stop_lo:
            th_new, w_new = self.stop_lo, max(w_new, 0.0)
        elif th_new >= self.stop_hi:
            th_new, w_new = self.stop_hi, min(w_new, 0.0)
        self.th, self.w = th_new, w_new
        a, b0, b1 = self._pa, self._pb0, self._pb1
        self.p_head = a * self.p_head + b0 * h_now + b1 * h_prev
        self.p_rod = a * self.p_rod + b0 * r_now + b1 * r_prev
        self._k = k + 1

    def _friction_torque(self, w: float, w_lin: float, gt_w: float) -> tuple[float, bool]:
        """Friction torque [N m] held over this step, given the velocity without friction and
        ``gt_w``, the velocity [deg/s] a N m held over a step makes; and whether it holds the
        joint still."""
        p = self.params
        if w != 0.0:
            magnitude = p.Fc + (p.Fs - p.Fc) * math.exp(-((abs(w) / p.vs) ** p.alpha))
            f = magnitude * math.tanh(p.beta * w / p.vs)
            w_try = w_lin - gt_w * f
            if (w_try > 0.0) == (w > 0.0) and w_try != 0.0:
                return f, False  # slipping on, same direction
        # At rest, or the step would stop or reverse the joint: can static friction hold it?
        hold = w_lin / gt_w
        if abs(hold) <= p.Fs:
            return hold, True
        return math.copysign(p.Fs, hold), False  # breakaway: moves in the direction of the net torque
