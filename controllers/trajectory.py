"""Joint references the loop follows: set-point moves, the reference paths of rig-facts §1,
waypoint paths (joint or Cartesian) and step sequences.

Time scaling is the cubic polynomial of [2-15..2-28] with zero velocity at both ends:
``s(tau) = 3 tau^2 - 2 tau^3``, ``tau = t / T``. Cartesian paths are mapped to joint angles by the
2-link inverse kinematics [2-9..2-14]; joint velocity comes from the inverse Jacobian and
acceleration from its central difference. Angles in rad, positions in m, time in s, with
``t`` measured from the trajectory's start.
"""
from __future__ import annotations

import itertools
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

from hal import kinematics

Sample = tuple[list[float], list[float], list[float]]  # angles, velocities, accelerations


def cubic(tau: float) -> tuple[float, float, float]:
    """s, ds/dtau, d2s/dtau2 of the cubic time scaling, tau clamped to [0, 1]."""
    if tau <= 0.0:
        return 0.0, 0.0, 0.0
    if tau >= 1.0:
        return 1.0, 0.0, 0.0
    return 3 * tau * tau - 2 * tau ** 3, 6 * tau - 6 * tau * tau, 6 - 12 * tau


class Trajectory(ABC):
    duration: float  # [s]; after it, the trajectory holds its last sample

    @abstractmethod
    def sample(self, t: float) -> Sample:
        """Reference angles [rad], velocities [rad/s], accelerations [rad/s^2] at time t [s]."""

    @property
    def end(self) -> list[float]:
        return self.sample(self.duration)[0]


class Hold(Trajectory):
    """Stay at fixed angles."""

    def __init__(self, angles: Sequence[float]):
        self.angles = list(angles)
        self.duration = 0.0
        self._zeros = [0.0] * len(angles)

    def sample(self, t: float) -> Sample:
        return self.angles, self._zeros, self._zeros


class JointMove(Trajectory):
    """From q0 to q1 [rad] over ``duration`` with cubic scaling (a step when duration is 0)."""

    def __init__(self, q0: Sequence[float], q1: Sequence[float], duration: float):
        self.q0, self.dq = list(q0), [b - a for a, b in zip(q0, q1)]
        self.duration = max(duration, 0.0)

    def sample(self, t: float) -> Sample:
        if self.duration == 0.0:
            s, ds, dds = (1.0, 0.0, 0.0)
            scale = 0.0
        else:
            s, ds, dds = cubic(t / self.duration)
            scale = 1.0 / self.duration
        return ([a + d * s for a, d in zip(self.q0, self.dq)], [d * ds * scale for d in self.dq],
                [d * dds * scale * scale for d in self.dq])


class CartesianPath(Trajectory):
    """A planar tip path p(sigma), sigma in [0, 1] run with cubic scaling over ``duration``."""

    def __init__(self, name: str, point: Callable[[float], tuple[float, float]],
                 tangent: Callable[[float], tuple[float, float]], duration: float,
                 lengths: Sequence[float], elbow: int, n_joints: int):
        if duration <= 0:
            raise ValueError(f"{name}: duration must be > 0 s, got {duration}")
        if len(lengths) < 2:
            raise ValueError(f"{name}: a planar path needs a 2-link arm")
        self.name, self.point, self.tangent, self.duration = name, point, tangent, duration
        self.l1, self.l2, self.elbow = lengths[0], lengths[1], elbow
        self._rest = [0.0] * (n_joints - 2)  # joints beyond the planar two are held at 0 rad

    def tip(self, t: float) -> tuple[float, float]:
        return self.point(cubic(t / self.duration)[0])

    def sample(self, t: float) -> Sample:
        q, qd = self._angles_and_rates(t)
        h = 1e-3
        _, qd_a = self._angles_and_rates(t - h)
        _, qd_b = self._angles_and_rates(t + h)
        qdd = [(b - a) / (2 * h) for a, b in zip(qd_a, qd_b)]
        return q + self._rest, qd + self._rest, qdd + self._rest

    def _angles_and_rates(self, t: float) -> tuple[list[float], list[float]]:
        s, ds, _ = cubic(t / self.duration)
        x, y = self.point(s)
        q = list(kinematics.inverse_2link(x, y, self.l1, self.l2, self.elbow))
        tx, ty = self.tangent(s)
        rate = ds / self.duration
        vx, vy = tx * rate, ty * rate
        (a, c), (b, d) = kinematics.jacobian(q, (self.l1, self.l2))  # columns: (dx, dy) per joint
        det = a * d - b * c
        return q, [(d * vx - b * vy) / det, (-c * vx + a * vy) / det]


def line(lengths, elbow, n_joints, duration, start_mm, end_mm, name="line"):
    """A straight tip path from start_mm to end_mm [mm] with cubic time scaling."""
    (x0, y0), (x1, y1) = [(a * 1e-3, b * 1e-3) for a, b in (start_mm, end_mm)]
    return CartesianPath(name, lambda s: (x0 + (x1 - x0) * s, y0 + (y1 - y0) * s),
                         lambda s: (x1 - x0, y1 - y0), duration, lengths, elbow, n_joints)


def translation(lengths, elbow, n_joints, duration=15.0, start_mm=(70.0, 135.0), end_mm=(-20.0, 135.0)):
    """rig-facts §1 translation mode: (70, 135) -> (-20, 135) mm in 15 s."""
    return line(lengths, elbow, n_joints, duration, start_mm, end_mm, "translation")


def circle(lengths, elbow, n_joints, duration=20.0, centre_mm=(50.0, 138.0), radius_mm=35.0):
    """rig-facts §1 circular mode: centre (50, 138) mm, radius 35 mm, one revolution."""
    cx, cy, r = centre_mm[0] * 1e-3, centre_mm[1] * 1e-3, radius_mm * 1e-3
    two_pi = 2 * math.pi
    return CartesianPath("circle", lambda s: (cx + r * math.cos(two_pi * s), cy + r * math.sin(two_pi * s)),
                         lambda s: (-r * two_pi * math.sin(two_pi * s), r * two_pi * math.cos(two_pi * s)),
                         duration, lengths, elbow, n_joints)


class Chain(Trajectory):
    """Trajectories one after another (e.g. an approach move, then a path)."""

    def __init__(self, parts: Sequence[Trajectory]):
        self.parts = list(parts)
        self.duration = sum(p.duration for p in self.parts)

    def sample(self, t: float) -> Sample:
        for part in self.parts[:-1]:
            if t < part.duration:
                return part.sample(t)
            t -= part.duration
        return self.parts[-1].sample(t)


def joint_waypoints(points: Sequence[Sequence[float]], durations: Sequence[float]) -> "Chain":
    """Through joint-space points [rad], segment i (to point i + 1) taking durations[i] [s]
    with cubic time scaling: at rest at every point."""
    return Chain([JointMove(a, b, d) for a, b, d in zip(points, points[1:], durations)])


def cartesian_waypoints(lengths, elbow, n_joints, points_mm: Sequence[Sequence[float]],
                        durations: Sequence[float]) -> "Chain":
    """Straight tip lines through points [mm], each with its duration [s] and cubic time scaling."""
    return Chain([line(lengths, elbow, n_joints, d, a, b, f"segment {i + 1}")
                  for i, (a, b, d) in enumerate(zip(points_mm, points_mm[1:], durations))])


class Steps(Trajectory):
    """A step sequence: jump to levels[i] [rad] and hold it for holds[i] [s], one after another."""

    def __init__(self, levels: Sequence[Sequence[float]], holds: Sequence[float]):
        self.levels = [list(q) for q in levels]
        self.ends = list(itertools.accumulate(holds))
        self.duration = self.ends[-1]
        self._zeros = [0.0] * len(self.levels[0])

    def sample(self, t: float) -> Sample:
        for level, end in zip(self.levels, self.ends):
            if t < end:
                return level, self._zeros, self._zeros
        return self.levels[-1], self._zeros, self._zeros


def check_within_limits(trajectory: Trajectory, limits: Sequence[tuple[float, float]], names: Sequence[str],
                        samples: int = 400) -> None:
    """Raise ValueError naming the joint, time and angle if the trajectory leaves the limits."""
    for i in range(samples + 1):
        t = trajectory.duration * i / samples
        q = trajectory.sample(t)[0]
        for name, angle, (lo, hi) in zip(names, q, limits):
            if not lo <= angle <= hi:
                raise ValueError(f"joint {name} would reach {math.degrees(angle):.1f} deg at t = {t:.2f} s, "
                                 f"outside its limits {math.degrees(lo):.1f}..{math.degrees(hi):.1f} deg")
