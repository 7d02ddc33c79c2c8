"""Feasibility before motion: can the rig's authority deliver a joint reference?

Rig-facts §1 "Authority that follows": V_MV spans the bias to the 0-10 V edges (-4..+6 V at a
4 V bias), and the speed a joint reaches is what the viscous term, the spring about th_0 and
Coulomb friction leave of that torque. Along the reference, sampled every ``step_s``, the
volts that hold the motion in steady state (:meth:`NominalJoint.static_volts`,
J th'' + D th' + K (th - th_0) + Fc sgn th' - tau_bias = kt V_MV) must stay within the fraction
``limits.authority_fraction`` of the range (below 1 leaves a margin to feedback). A refusal carries the numbers:
needed and available volts, head-chamber pressure and speed, where and when.

A step (a zero-duration move, a step sequence, a PRBS level) is checked at its levels: the
rig must be able to hold each one; how fast it gets there is the controller's saturation.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from controllers.nominal import NominalJoint
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


@dataclass(frozen=True)
class Authority:
    """What the configured rig can deliver, per joint."""

    names: Sequence[str]
    models: Sequence[NominalJoint]
    u_min: Sequence[float]
    u_max: Sequence[float]
    bias_volts: Sequence[float]
    fraction: float  # of the V_MV range a reference may ask for in steady state (limits.authority_fraction)

    @classmethod
    def of(cls, rig, context, fraction: float) -> "Authority":
        return cls(context.joint_names, context.models, context.u_min, context.u_max,
                   [j.head.bias_volts for j in rig.joints], fraction)

    def usable(self, j: int) -> tuple[float, float]:
        return self.u_min[j] * self.fraction, self.u_max[j] * self.fraction

    def shortfalls(self, trajectory: Trajectory, step_s: float = 0.05) -> list[Shortfall]:
        """The worst excess per joint along the reference (empty when feasible)."""
        worst: dict[int, tuple[float, Shortfall]] = {}
        count = max(int(math.ceil(trajectory.duration / step_s)), 1)
        for i in range(count + 1):
            t = trajectory.duration * i / count
            q, w, a = trajectory.sample(t)
            for j, m in enumerate(self.models):
                if m is None:
                    continue
                volts = m.static_volts(q[j], w[j], a[j])
                lo, hi = self.usable(j)
                excess = max(lo - volts, volts - hi)
                if excess > 1e-9 and excess > worst.get(j, (0.0, None))[0]:
                    worst[j] = (excess, Shortfall(self.names[j], t, q[j], w[j], volts, (lo, hi), self.bias_volts[j]))
        return [s for _, s in (worst[j] for j in sorted(worst))]

    def top_speeds(self) -> dict[str, float]:
        """Speed at full positive V_MV at each joint's neutral angle [rad/s] (rig-facts §1)."""
        return {n: m.top_speed(m.neutral, hi) for n, m, hi in zip(self.names, self.models, self.u_max) if m is not None}

    def check(self, make: Callable[[float], Trajectory], duration: float, longest_s: float = 3600.0,
              fixed: str | None = None) -> Trajectory:
        """The reference ``make(duration)`` if feasible; else Infeasible with the shortest
        duration (to 0.1 s) that would be, found by bisection (speeds scale as 1/T). A
        reference whose demands do not fall with its duration (steps, excitation signals)
        passes ``fixed``: the remedy the refusal suggests instead."""
        trajectory = make(duration)
        shortfalls = self.shortfalls(trajectory)
        if not shortfalls:
            return trajectory
        if fixed is not None:
            raise Infeasible(shortfalls, None, self.top_speeds(), fixed)
        shortest = None
        if not self.shortfalls(make(longest_s)):
            lo, hi = duration, longest_s
            while hi - lo > 0.05:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if not self.shortfalls(make(mid)) else (mid, hi)
            shortest = math.ceil(hi * 10.0) / 10.0
        raise Infeasible(shortfalls, shortest, self.top_speeds())
