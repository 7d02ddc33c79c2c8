"""Feasibility before motion: can the rig's authority deliver a joint reference?

Rig-facts §1 "Authority that follows": V_MV spans the bias to the 0-10 V edges (-4..+6 V at a
4 V bias), and the speed a joint reaches is what the viscous term, the spring about th_0 and
Coulomb friction leave of that torque. Along the reference's profile
(:meth:`~controllers.trajectory.Trajectory.profile`), the volts that hold the motion in steady
state (:meth:`NominalJoint.static_volts`, J th'' + D th' + K (th - th_0) + Fc sgn th' - tau_bias
= kt V_MV, plus a known payload's holding volts, controllers.known_load) must stay within the
fraction ``limits.authority_fraction`` of the range (below 1 leaves a margin to feedback). A refusal carries the numbers: needed and available volts,
head-chamber pressure and speed, where and when.

The shortest feasible duration comes from the shape, not from trying durations. A time-scaled
reference run in T instead of its own T0 has rates x w0 and accelerations x^2 a0 (x = T0 / T),
so at each profile sample the volts are the quadratic alpha x^2 + beta x + c (alpha = J a0 / kt,
beta = D w0 / kt, c = the spring, friction and bias terms); the smallest positive x at which any
sample reaches a limit gives the shortest T = T0 / x, below which no duration is feasible and
above which every one is. The check is exact at any duration: a 1 ms move is refused as the
step it would be, with the duration that would do.

A step (a zero-duration move, a step sequence, a PRBS level) and an excitation signal are
checked where they are hardest: the rig must be able to hold each level or follow the signal;
how fast a step gets there is the controller's saturation.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controllers.known_load import KnownLoad
from controllers.nominal import NominalJoint
from controllers.profile import Profile
from controllers.trajectory import Trajectory
from hal.identified import K_EP


@dataclass(frozen=True)
class Shortfall:
    """The worst point of one joint where the reference asks for more than the rig has."""

    joint: str
    t: float  # [s] from the reference's start
    angle: float  # [rad]
    speed: float  # needed [rad/s]
    volts: float  # needed V_MV [V]
    available: tuple[float, float]  # usable V_MV range [V]
    bias_volts: float  # head-chamber bias [V]

    def describe(self) -> str:
        lo, hi = self.available
        limit = lo if self.volts < lo else hi
        p_need = (self.bias_volts + self.volts) * K_EP * 1e-6
        p_have = max((self.bias_volts + limit) * K_EP * 1e-6, 0.0)
        need = f"{p_need:.3f} MPa" if p_need >= 0 else "below 0 MPa"
        return (f"joint {self.joint} at t = {self.t:.2f} s ({math.degrees(self.angle):.1f} deg, "
                f"{math.degrees(self.speed):+.2f} deg/s) needs V_MV {self.volts:+.2f} V "
                f"(head chamber {need}) but {limit:+.2f} V ({p_have:.3f} MPa) is what it may use")


class Infeasible(ValueError):
    def __init__(self, shortfalls: list[Shortfall], shortest_s: float | None, top_speeds: dict[str, float],
                 remedy: str = "no duration makes it feasible (the end points themselves are out of reach)"):
        self.shortfalls, self.shortest_s, self.top_speeds = shortfalls, shortest_s, top_speeds
        text = "; ".join(s.describe() for s in shortfalls)
        speeds = ", ".join(f"{name} {math.degrees(v):.1f} deg/s" for name, v in top_speeds.items())
        hint = f"the shortest feasible duration is {shortest_s:.1f} s" if shortest_s is not None else remedy
        super().__init__(f"beyond the rig's authority: {text} (top speeds at the neutral angle: {speeds}); {hint}")

    def data(self) -> dict:
        """The refusal as numbers, for a client that must not parse English."""
        return {"reason": "authority", "shortest_s": self.shortest_s,
                "shortfalls": [{"joint": s.joint, "t_s": s.t, "angle_deg": math.degrees(s.angle),
                                "speed_deg_s": math.degrees(s.speed), "needed_volts": s.volts,
                                "available_volts": list(s.available)} for s in self.shortfalls]}


@dataclass(frozen=True)
class Authority:
    """What the configured rig can deliver, per joint."""

    names: Sequence[str]
    models: Sequence[NominalJoint]
    u_min: Sequence[float]
    u_max: Sequence[float]
    bias_volts: Sequence[float]
    fraction: float  # of the V_MV range a reference may ask for in steady state (limits.authority_fraction)
    load: KnownLoad | None = None  # a known payload: its holding volts count against the range

    @classmethod
    def of(cls, rig, context, fraction: float) -> "Authority":
        return cls(context.joint_names, context.models, context.u_min, context.u_max,
                   [j.head.bias_volts for j in rig.joints], fraction)

    def usable(self, j: int) -> tuple[float, float]:
        return self.u_min[j] * self.fraction, self.u_max[j] * self.fraction

    def _terms(self, profile: Profile, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """alpha, beta, c of joint j's volts alpha x^2 + beta x + c at rate scale x [V]."""
        m = self.models[j]
        q, w, a = profile.q[:, j], profile.w[:, j], profile.a[:, j]
        c = (m.K * (q - m.neutral) + m.Fc * np.sign(w) - m.bias_torque) / m.kt
        if self.load is not None:
            c = c + self.load.volts_along(profile.q)[:, j]
        return m.J * a / m.kt, m.D * w / m.kt, c

    def shortfalls(self, trajectory: Trajectory | Profile) -> list[Shortfall]:
        """The worst excess per joint along the reference (empty when feasible)."""
        profile = trajectory if isinstance(trajectory, Profile) else trajectory.profile()
        found = []
        for j, m in enumerate(self.models):
            if m is None:
                continue
            alpha, beta, c = self._terms(profile, j)
            volts = alpha + beta + c
            lo, hi = self.usable(j)
            excess = np.maximum(lo - volts, volts - hi)
            i = int(np.argmax(excess))
            if excess[i] > 1e-9:
                found.append(Shortfall(self.names[j], float(profile.t[i]), float(profile.q[i, j]),
                                       float(profile.w[i, j]), float(volts[i]), (lo, hi), self.bias_volts[j]))
        return found

    def shortest(self, trajectory: Trajectory) -> float | None:
        """The shortest duration [s] at which this time-scaled reference, and every slower
        run of it, is feasible: 0 if any is; None if none is (its rest points are beyond the
        rig, or it is not a time-scaled shape)."""
        if not trajectory.scalable or trajectory.duration <= 0:
            return 0.0 if not self.shortfalls(trajectory) else None
        profile = trajectory.profile()
        x_limit = math.inf
        for j, m in enumerate(self.models):
            if m is None:
                continue
            alpha, beta, c = self._terms(profile, j)
            lo, hi = self.usable(j)
            if (c > hi + 1e-9).any() or (c < lo - 1e-9).any():
                return None
            x_limit = min(x_limit, _first_root(alpha, beta, c - hi), _first_root(alpha, beta, c - lo))
        return 0.0 if math.isinf(x_limit) else trajectory.duration / x_limit

    def top_speeds(self) -> dict[str, float]:
        """Speed at full positive V_MV at each joint's neutral angle [rad/s] (rig-facts §1)."""
        return {n: m.top_speed(m.neutral, hi) for n, m, hi in zip(self.names, self.models, self.u_max) if m is not None}

    def check(self, trajectory: Trajectory, fixed: str | None = None) -> None:
        """Nothing if the rig can deliver ``trajectory``; else Infeasible with the shortest
        duration that would do (to 0.1 s, rounded up). A reference whose demands do not fall
        with its duration passes ``fixed``: the remedy the refusal suggests instead."""
        shortfalls = self.shortfalls(trajectory)
        if not shortfalls:
            return
        if fixed is not None or not trajectory.scalable:
            raise Infeasible(shortfalls, None, self.top_speeds(), fixed or "no duration makes it feasible")
        shortest = self.shortest(trajectory)
        raise Infeasible(shortfalls, None if shortest is None else max(math.ceil(shortest * 10.0) / 10.0, 0.1),
                         self.top_speeds())


def _first_root(alpha: np.ndarray, beta: np.ndarray, gamma: np.ndarray) -> float:
    """The smallest x > 0 at which any alpha x^2 + beta x + gamma crosses zero (inf if none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        linear = -gamma / beta
        root = np.sqrt(beta * beta - 4.0 * alpha * gamma)
        r1, r2 = (-beta - root) / (2.0 * alpha), (-beta + root) / (2.0 * alpha)
    is_linear = alpha == 0.0
    candidates = np.stack([np.where(is_linear, linear, r1), np.where(is_linear, np.nan, r2)])
    candidates = np.where(candidates > 1e-12, candidates, np.inf)  # NaN (no real root) and x <= 0 drop out
    return float(np.min(candidates)) if candidates.size else math.inf
