"""Feasibility before motion on a linear pneumatic axis (rig-facts §5): can the valve's flow and
the cylinder's force deliver a position reference? SI inside (m, m/s, m/s^2, N), mm at the edge.

The axis's own limits (:func:`hal.linear_axis_facts.facts`, at mid-stroke):

- **flow**: the speed a held valve command drives the piston to under its load is bounded by the
  top speed at a fully open valve (``steady_motion``: 0.80 m/s extending and 0.67 m/s
  retracting on ``sim-axis``); a reference may ask ``limits.authority_fraction`` of it;
- **force**: along the reference the piston needs ``F = M a + beta v + Fc sgn v - F_load``
  (the equation of motion of :mod:`hal.linear_axis`, friction at Coulomb's), which the chambers
  give up to the stall force (the most the axis pushes, held still at 10 V, or pulls at 0 V);
  a reference may ask the same fraction of it.

As for the cylinder joints (:mod:`controllers.feasibility`), a time-scaled reference run in T
instead of T0 (x = T0 / T) has speeds x w0 and accelerations x^2 a0, so the shortest feasible
duration follows from the shape: the smallest x at which a sample's speed reaches its bound
(x = v_top / |w0|) or its force its bound (the quadratic M a0 x^2 + beta w0 x + c).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controllers.feasibility import Infeasible, _first_root
from controllers.profile import Profile
from controllers.trajectory import Trajectory
from hal.linear_axis import AxisParams
from hal.linear_axis_facts import AxisFacts, facts


@dataclass(frozen=True)
class AxisShortfall:
    """The worst point of one axis where the reference asks for more than it has."""

    joint: str
    t: float  # [s] from the reference's start
    position: float  # [m]
    speed: float  # needed [m/s]
    force: float  # needed [N]
    speed_bound: float  # usable top speed that way [m/s]
    force_bound: tuple[float, float]  # usable force range [N]

    def describe(self) -> str:
        lo, hi = self.force_bound
        if abs(self.speed) > self.speed_bound:
            why = f"but the valve's flow gives {self.speed_bound * 1e3:.0f} mm/s that way"
        else:
            why = f"but the cylinder gives {lo:.0f}..{hi:.0f} N"
        return (f"joint {self.joint} at t = {self.t:.2f} s ({self.position * 1e3:.1f} mm, "
                f"{self.speed * 1e3:+.1f} mm/s) needs {self.force:+.1f} N {why}")


class AxisInfeasible(Infeasible):
    """An axis's refusal: its shortfalls and top speeds in mm, mm/s and N."""

    def __init__(self, shortfalls: list[AxisShortfall], shortest_s: float | None, top_speeds: dict[str, float],
                 remedy: str = "no duration makes it feasible"):
        self.shortfalls, self.shortest_s, self.top_speeds = shortfalls, shortest_s, top_speeds
        text = "; ".join(s.describe() for s in shortfalls)
        speeds = ", ".join(f"{name} {v * 1e3:.0f} mm/s" for name, v in top_speeds.items())
        hint = f"the shortest feasible duration is {shortest_s:.1f} s" if shortest_s is not None else remedy
        ValueError.__init__(self, f"beyond the axis's flow or force: {text} (usable top speeds: {speeds}); {hint}")

    def data(self) -> dict:
        return {"reason": "authority", "shortest_s": self.shortest_s,
                "shortfalls": [{"joint": s.joint, "t_s": s.t, "position_mm": s.position * 1e3,
                                "speed_mm_s": s.speed * 1e3, "needed_n": s.force,
                                "top_speed_mm_s": s.speed_bound * 1e3, "available_n": list(s.force_bound)}
                               for s in self.shortfalls]}


@dataclass(frozen=True)
class AxisAuthority:
    """What each axis of the configured rig can deliver. ``models``, ``load``, ``u_min``,
    ``u_max``: what the excitation planner reads of any authority (no nominal joint model, no
    known payload; the valve's command range [V about its centre])."""

    names: Sequence[str]
    axes: Sequence[AxisParams]
    figures: Sequence[AxisFacts]
    u_min: Sequence[float]
    u_max: Sequence[float]
    fraction: float  # of the top speed and the stall force a reference may ask for (limits.authority_fraction)
    load = None

    @classmethod
    def of(cls, context, fraction: float) -> "AxisAuthority":
        axes = tuple(context.axes)
        return cls(context.joint_names, axes, tuple(facts(a) for a in axes), context.u_min, context.u_max, fraction)

    @property
    def models(self) -> tuple[None, ...]:
        return (None,) * len(self.names)

    def _bounds(self, j: int) -> tuple[float, float, float, float]:
        """(top speed extending, retracting [m/s], force pulling (< 0), pushing [N]), usable."""
        f, k = self.figures[j], self.fraction
        return (k * f.max_speed_extend_m_s, k * f.max_speed_retract_m_s, -k * f.stall_force_retract_n,
                k * f.stall_force_extend_n)

    def _terms(self, profile: Profile, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """alpha, beta, c of joint j's force alpha x^2 + beta x + c at rate scale x [N]."""
        a = self.axes[j]
        w = profile.w[:, j]
        return a.moving_mass_kg * profile.a[:, j], a.viscous_n_s_m * w, a.coulomb_n * np.sign(w) - a.load_force_n

    def shortfalls(self, trajectory: Trajectory | Profile) -> list[AxisShortfall]:
        profile = trajectory if isinstance(trajectory, Profile) else trajectory.profile()
        found = []
        for j in range(len(self.names)):
            v_out, v_in, f_lo, f_hi = self._bounds(j)
            alpha, beta, c = self._terms(profile, j)
            force = alpha + beta + c
            w = profile.w[:, j]
            bound = np.where(w >= 0, v_out, v_in)
            excess = np.maximum(np.maximum(f_lo - force, force - f_hi) / max(f_hi, 1e-9), (np.abs(w) - bound) / bound)
            i = int(np.argmax(excess))
            if excess[i] > 1e-9:
                found.append(AxisShortfall(self.names[j], float(profile.t[i]), float(profile.q[i, j]), float(w[i]),
                                           float(force[i]), float(bound[i]), (f_lo, f_hi)))
        return found

    def shortest(self, trajectory: Trajectory) -> float | None:
        """The shortest duration [s] at which this time-scaled reference and every slower run of
        it is feasible: 0 if any is; None if none is (its rest points are beyond the axis)."""
        if not trajectory.scalable or trajectory.duration <= 0:
            return 0.0 if not self.shortfalls(trajectory) else None
        profile = trajectory.profile()
        x_limit = math.inf
        for j in range(len(self.names)):
            v_out, v_in, f_lo, f_hi = self._bounds(j)
            alpha, beta, c = self._terms(profile, j)
            if (c > f_hi + 1e-9).any() or (c < f_lo - 1e-9).any():
                return None
            w = profile.w[:, j]
            with np.errstate(divide="ignore"):
                by_speed = np.where(w > 0, v_out / w, np.where(w < 0, -v_in / w, np.inf))
            x_limit = min(x_limit, float(np.min(by_speed)) if by_speed.size else math.inf,
                          _first_root(alpha, beta, c - f_hi), _first_root(alpha, beta, c - f_lo))
        return 0.0 if math.isinf(x_limit) else trajectory.duration / x_limit

    def top_speeds(self) -> dict[str, float]:
        """The usable top speed extending per axis [m/s]."""
        return {n: self._bounds(j)[0] for j, n in enumerate(self.names)}

    def check(self, trajectory: Trajectory, fixed: str | None = None) -> None:
        """Nothing if the axis can deliver ``trajectory``; else AxisInfeasible with the shortest
        duration that would do (to 0.1 s, rounded up), or ``fixed``'s remedy."""
        shortfalls = self.shortfalls(trajectory)
        if not shortfalls:
            return
        if fixed is not None or not trajectory.scalable:
            raise AxisInfeasible(shortfalls, None, self.top_speeds(), fixed or "no duration makes it feasible")
        shortest = self.shortest(trajectory)
        raise AxisInfeasible(shortfalls, None if shortest is None else max(math.ceil(shortest * 10.0) / 10.0, 0.1),
                             self.top_speeds())
