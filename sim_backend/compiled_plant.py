"""The planar arm of regulator-driven cylinder joints (:class:`sim_backend.plant.SimArm`), its
step compiled with numba: the same model and the same discretisation, for evaluations that run
millions of steps (``pneumactl evaluate``: docs/controllers.md, docs/benchmarks.md).

The Python plant stays the reference: this one takes every coefficient from the Python joints
built on the same rig and options (:class:`hal.joint_model.JointModel`: exact ZOH rows,
the dead-time split, the chamber lag) and only the per-step arithmetic runs compiled, the same
operations in the same order ([2-36..2-39], [2-45] through :func:`stribeck_step`'s Newton step),
so the two give equal trajectories to float rounding (tests/test_compiled_plant.py).

Covered: the Stribeck friction model or none, dead time on or off, external torques per joint.
Refused (ConfigError, the Python plant models them): Karnopp friction, a payload, the wall, the
injected faults of docs/model.md.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from hal.errors import ConfigError
from hal.identified import K_EP, P_OFFSET, P_SET_MAX, P_SET_MIN, SUPPLY_HEADROOM
from sim_backend.plant import SimArm

# coef columns per joint: the 12 rows of JointModel._rows, then spring [N m], c, A_H, A_L,
# Fc, Fs - Fc, vs, alpha, beta, chamber lag a, b0, b1, stop low, stop high [deg], friction (0/1),
# delay steps, buffer size
_ROWS, _SPRING, _C, _AH, _AL, _FRIC, _LAG, _STOPS, _HAS_FRICTION, _DELAY, _SIZE = 0, 12, 13, 14, 15, 16, 21, 24, 26, 27, 28
_WIDTH = 29


@numba.njit(cache=True)
def _stribeck(fc, drop, vs, alpha, beta, w, w_lin, g):
    """:func:`hal.joint_model.stribeck_step`, compiled (the same operations)."""
    if w_lin == 0.0:
        return 0.0
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
    if w_lin > 0.0:
        v = min(max(v, 0.0), w_lin)
    else:
        v = max(min(v, 0.0), w_lin)
    return (w_lin - v) / g


@numba.njit(cache=True)
def _regulator(volts, supply_pa, k_ep, offset, p_min, p_max, headroom):
    """:func:`sim_backend.plant.regulator_output`, compiled."""
    v = min(max(volts, 0.0), 10.0)
    p = min(max(k_ep * v + offset, p_min), p_max)
    ceiling = min(max(supply_pa - headroom, 0.0), p_max)
    return p if p < ceiling else ceiling


@numba.njit(cache=True)
def _advance(coef, buf, state, k, volts, tau_ext, supply_pa, reg, steps):
    """``steps`` plant steps with ``volts`` (head, rod per joint) held; state per joint:
    [th deg, w deg/s, p_head Pa, p_rod Pa]; buf[j, 0|1, :] the set pressures' delay lines."""
    for _ in range(steps):
        for j in range(coef.shape[0]):
            c = coef[j]
            size = int(c[_SIZE])
            delay = int(c[_DELAY])
            kk = k[j]
            ph = _regulator(volts[2 * j], supply_pa, reg[0], reg[1], reg[2], reg[3], reg[4])
            pr = _regulator(volts[2 * j + 1], supply_pa, reg[0], reg[1], reg[2], reg[3], reg[4])
            buf[j, 0, kk % size] = ph
            buf[j, 1, kk % size] = pr
            i_now, i_prev = (kk - delay) % size, (kk - delay - 1) % size
            h_now, r_now = buf[j, 0, i_now], buf[j, 1, i_now]
            h_prev, r_prev = buf[j, 0, i_prev], buf[j, 1, i_prev]
            cc, ah, al = c[_C], c[_AH], c[_AL]
            t_now = cc * (ah * h_now - al * r_now)
            t_prev = cc * (ah * h_prev - al * r_prev)
            torque = cc * (ah * state[j, 2] - al * state[j, 3])
            tau = c[_SPRING] + tau_ext[j]
            th, w = state[j, 0], state[j, 1]
            th_lin = c[0] * torque + c[1] * th + c[2] * w + c[3] * t_now + c[4] * t_prev + c[5] * tau
            w_lin = c[6] * torque + c[7] * th + c[8] * w + c[9] * t_now + c[10] * t_prev + c[11] * tau
            if c[_HAS_FRICTION] != 0.0:
                f = _stribeck(c[_FRIC], c[_FRIC + 1], c[_FRIC + 2], c[_FRIC + 3], c[_FRIC + 4], w, w_lin, c[11])
                th_new, w_new = th_lin - c[5] * f, w_lin - c[11] * f
            else:
                th_new, w_new = th_lin, w_lin
            if th_new <= c[_STOPS]:
                th_new, w_new = c[_STOPS], max(w_new, 0.0)
            elif th_new >= c[_STOPS + 1]:
                th_new, w_new = c[_STOPS + 1], min(w_new, 0.0)
            state[j, 0], state[j, 1] = th_new, w_new
            a, b0, b1 = c[_LAG], c[_LAG + 1], c[_LAG + 2]
            state[j, 2] = a * state[j, 2] + b0 * h_now + b1 * h_prev
            state[j, 3] = a * state[j, 3] + b0 * r_now + b1 * r_prev
            k[j] = kk + 1


class CompiledArm(SimArm):
    """:class:`SimArm` with its step compiled (module docstring); built, checked and read the same."""

    def __init__(self, rig, options):
        super().__init__(rig, options)
        if options.friction and options.friction_model != "stribeck":
            raise ConfigError("transport.options.compiled: the compiled plant models Stribeck friction only "
                              f"(friction_model {options.friction_model!r}: set compiled = false)")
        if options.payload.mass_kg or options.wall.enabled:
            raise ConfigError("transport.options.compiled: the compiled plant has no payload or wall "
                              "(set compiled = false)")
        if any(drift is not None for drift in self._drifts):
            raise ConfigError("transport.options.compiled: the compiled plant has no injected faults (a leak, "
                              "friction_scale, sensor_offset_deg, regulator_gain: set compiled = false)")
        self._reg = np.array([K_EP, P_OFFSET, P_SET_MIN, P_SET_MAX, SUPPLY_HEADROOM])
        n = len(self.joints)
        size = max(len(j._buf_head) for j in self.joints)
        self._coef = np.zeros((n, _WIDTH))
        self._buf = np.zeros((n, 2, size))
        self._state = np.zeros((n, 4))
        self._k = np.zeros(n, dtype=np.int64)
        for i, jm in enumerate(self.joints):
            c = self._coef[i]
            c[:12] = jm._rows
            c[_SPRING], c[_C], c[_AH], c[_AL] = jm._spring_nm, jm._c, jm._ah, jm._al
            c[_FRIC:_FRIC + 5] = jm._friction
            c[_LAG:_LAG + 3] = jm._pa, jm._pb0, jm._pb1
            c[_STOPS:_STOPS + 2] = jm.stop_lo, jm.stop_hi
            c[_HAS_FRICTION], c[_DELAY], c[_SIZE] = float(jm.friction), jm.delay_steps, len(jm._buf_head)
            self._buf[i, 0, :len(jm._buf_head)] = jm._buf_head
            self._buf[i, 1, :len(jm._buf_rod)] = jm._buf_rod
            self._state[i] = jm.th, jm.w, jm.p_head, jm.p_rod
        self._volts = np.zeros(2 * n)
        self._tau = np.zeros(n)

    def step(self, volts) -> None:
        self.advance(volts, 1)

    def advance(self, volts, steps: int) -> None:
        """``steps`` steps with ``volts`` held, in one compiled call."""
        self._volts[:] = volts
        self._tau[:] = self.disturbance_nm
        _advance(self._coef, self._buf, self._state, self._k, self._volts, self._tau, self.supply_pa, self._reg, steps)

    def position(self, joint: int) -> float:
        return math.radians(self._state[joint, 0])

    def chamber_gauge(self, joint: int, second: bool) -> float:
        return float(self._state[joint, 3 if second else 2])

    def angles_rad(self) -> list[float]:
        return [math.radians(th) for th in self._state[:, 0].tolist()]

    def state_deg(self) -> list[tuple[float, float, float, float]]:
        """(th [deg], w [deg/s], p_head [Pa], p_rod [Pa]) per joint."""
        return [tuple(row) for row in self._state.tolist()]

