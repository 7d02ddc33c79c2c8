"""Joint references the loop follows: set-point moves, the reference paths of rig-facts §1,
waypoint paths (joint or Cartesian) and step sequences.

Time scaling is the cubic polynomial of [2-15..2-28] with zero velocity at both ends:
``s(tau) = 3 tau^2 - 2 tau^3``, ``tau = t / T``. Cartesian paths are mapped to joint angles by the
2-link inverse kinematics [2-9..2-14]; joint velocity and acceleration come from the inverse
Jacobian of [2-7] differentiated once and twice (:func:`hal.kinematics.rates_2link`). Angles in
rad, positions in m, time in s, with ``t`` measured from the trajectory's start.

Two sides, one object. The loop calls :meth:`Trajectory.sample` once a cycle: plain floats,
bounded work whatever the reference's size (a long waypoint path or step sequence finds its
segment by bisection). The planner, beside the loop, calls :meth:`Trajectory.profile`: the
demands (angle, rate, acceleration per joint) sampled along the whole reference as numpy
arrays (:mod:`controllers.profile`), for the limit and authority checks. A trajectory is built in the planner process
and sent to the loop whole, so it pickles small: long data are ``array('d')``, never lists
of lists or one object per segment.
"""
from __future__ import annotations

import bisect
import itertools
import math
from abc import ABC, abstractmethod
from array import array
from collections.abc import Sequence

import numpy as np

from controllers.profile import Profile, TipShape, cubic_array, tip_profile
from hal import kinematics

Sample = tuple[list[float], list[float], list[float]]  # angles, velocities, accelerations

PATH_POINTS = 401  # profile samples along one Cartesian path
MOVE_POINTS = 65  # ... along one cubic joint move
PROFILE_BUDGET = 40000  # profile samples along a whole chain of segments (the points per segment shrink)


def cubic(tau: float) -> tuple[float, float, float]:
    """s, ds/dtau, d2s/dtau2 of the cubic time scaling, tau clamped to [0, 1]."""
    if tau <= 0.0:
        return 0.0, 0.0, 0.0
    if tau >= 1.0:
        return 1.0, 0.0, 0.0
    return 3 * tau * tau - 2 * tau ** 3, 6 * tau - 6 * tau * tau, 6 - 12 * tau


class Trajectory(ABC):
    duration: float  # [s]; after it, the trajectory holds its last sample
    scalable = True  # its demands scale as 1/T (rates) and 1/T^2 (accelerations) with its duration T

    @abstractmethod
    def sample(self, t: float) -> Sample:
        """Reference angles [rad], velocities [rad/s], accelerations [rad/s^2] at time t [s]."""

    @abstractmethod
    def profile(self, points: int = 0) -> Profile:
        """The demands along the whole reference (``points`` per segment where that applies; 0:
        the trajectory's own default)."""

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

    def profile(self, points: int = 0) -> Profile:
        return Profile.at_rest(np.zeros(1), np.array([self.angles], dtype=float))


class Recorded(Trajectory):
    """A reference as a run recorded it: set-points [rad] at times [s] from its start, linear
    between them; velocities and accelerations by central differences of the samples (what a
    controller with feed-forward sees of it). Replays a recording's reference
    (``pneumactl replay``, docs/model.md)."""

    scalable = False

    def __init__(self, t: Sequence[float], q: np.ndarray):
        self.t = np.asarray(t, dtype=float) - float(t[0])
        self.q = np.asarray(q, dtype=float)
        if len(self.t) < 2 or self.q.shape[0] != len(self.t) or not np.all(np.diff(self.t) > 0):
            raise ValueError("a recorded reference needs two or more samples at rising times")
        self.w = np.gradient(self.q, self.t, axis=0)
        self.a = np.gradient(self.w, self.t, axis=0)
        self.duration = float(self.t[-1])

    def sample(self, t: float) -> Sample:
        t = min(max(t, 0.0), self.duration)
        k = min(int(np.searchsorted(self.t, t, side="right")) - 1, len(self.t) - 2)
        f = (t - self.t[k]) / (self.t[k + 1] - self.t[k])
        return [float(x) for x in self.q[k] + f * (self.q[k + 1] - self.q[k])], self.w[k].tolist(), self.a[k].tolist()

    def profile(self, points: int = 0) -> Profile:
        return Profile(self.t, self.q, self.w, self.a)


class JointMove(Trajectory):
    """From q0 to q1 [rad] over ``duration`` with cubic scaling (a step when duration is 0)."""

    def __init__(self, q0: Sequence[float], q1: Sequence[float], duration: float):
        self.q0, self.dq = [float(a) for a in q0], [float(b) - float(a) for a, b in zip(q0, q1)]
        self.duration = max(float(duration), 0.0)
        self.scalable = self.duration > 0.0  # a step is checked at its level

    def sample(self, t: float) -> Sample:
        if self.duration == 0.0:
            s, ds, dds = (1.0, 0.0, 0.0)
            scale = 0.0
        else:
            s, ds, dds = cubic(t / self.duration)
            scale = 1.0 / self.duration
        return ([a + d * s for a, d in zip(self.q0, self.dq)], [d * ds * scale for d in self.dq],
                [d * dds * scale * scale for d in self.dq])

    def profile(self, points: int = 0) -> Profile:
        q0, dq = np.array(self.q0), np.array(self.dq)
        if self.duration == 0.0:
            return Profile.at_rest(np.zeros(1), (q0 + dq)[None, :])
        tau = np.linspace(0.0, 1.0, points or MOVE_POINTS)
        s, ds, dds = cubic_array(tau)
        T = self.duration
        return Profile(tau * T, q0 + np.outer(s, dq), np.outer(ds / T, dq), np.outer(dds / T ** 2, dq))


class Line(TipShape):
    def __init__(self, start: tuple[float, float], end: tuple[float, float]):
        self.x0, self.y0 = start
        self.dx, self.dy = end[0] - start[0], end[1] - start[1]

    def point(self, s):
        return self.x0 + self.dx * s, self.y0 + self.dy * s

    def tangent(self, s):
        return self.dx, self.dy

    def curvature(self, s):
        return 0.0, 0.0

    def points(self, s):
        return self.x0 + self.dx * s, self.y0 + self.dy * s, np.full_like(s, self.dx), np.full_like(s, self.dy)


class Circle(TipShape):
    """One revolution anticlockwise from the point at angle 0."""

    def __init__(self, centre: tuple[float, float], radius: float):
        (self.cx, self.cy), self.r = centre, radius

    def point(self, s):
        a = 2 * math.pi * s
        return self.cx + self.r * math.cos(a), self.cy + self.r * math.sin(a)

    def tangent(self, s):
        a, k = 2 * math.pi * s, 2 * math.pi * self.r
        return -k * math.sin(a), k * math.cos(a)

    def curvature(self, s):
        a, k = 2 * math.pi * s, 4 * math.pi * math.pi * self.r
        return -k * math.cos(a), -k * math.sin(a)

    def points(self, s):
        a, k = 2 * math.pi * s, 2 * math.pi * self.r
        return self.cx + self.r * np.cos(a), self.cy + self.r * np.sin(a), -k * np.sin(a), k * np.cos(a)


class FigureEight(TipShape):
    """A lemniscate of Gerono about ``centre`` [m]: x = cx + a sin(2 pi s), y = cy + b sin(4 pi s) / 2,
    one loop each side, starting and ending at the centre."""

    def __init__(self, centre: tuple[float, float], half_width: float, half_height: float):
        (self.cx, self.cy), self.a, self.b = centre, half_width, half_height

    def point(self, s):
        return self.cx + self.a * math.sin(2 * math.pi * s), self.cy + 0.5 * self.b * math.sin(4 * math.pi * s)

    def tangent(self, s):
        return 2 * math.pi * self.a * math.cos(2 * math.pi * s), 2 * math.pi * self.b * math.cos(4 * math.pi * s)

    def curvature(self, s):
        k = 4 * math.pi * math.pi
        return -k * self.a * math.sin(2 * math.pi * s), -2 * k * self.b * math.sin(4 * math.pi * s)

    def points(self, s):
        w = 2 * math.pi * s
        return (self.cx + self.a * np.sin(w), self.cy + 0.5 * self.b * np.sin(2 * w),
                2 * math.pi * self.a * np.cos(w), 2 * math.pi * self.b * np.cos(2 * w))


class CartesianPath(Trajectory):
    """A planar tip path run with cubic scaling over ``duration``; joints beyond the planar
    two are held at 0 rad."""

    def __init__(self, name: str, shape: TipShape, duration: float, lengths: Sequence[float], elbow: int,
                 n_joints: int):
        if duration <= 0:
            raise ValueError(f"{name}: duration must be > 0 s, got {duration}")
        if len(lengths) < 2:
            raise ValueError(f"{name}: a planar path needs a 2-link arm")
        self.name, self.shape, self.duration = name, shape, float(duration)
        self.l1, self.l2, self.elbow = lengths[0], lengths[1], elbow
        self._rest = [0.0] * (n_joints - 2)

    def tip(self, t: float) -> tuple[float, float]:
        return self.shape.point(cubic(t / self.duration)[0])

    def sample(self, t: float) -> Sample:
        s, ds, dds = cubic(t / self.duration)
        x, y = self.shape.point(s)
        q1, q2 = kinematics.inverse_2link(x, y, self.l1, self.l2, self.elbow)
        tx, ty = self.shape.tangent(s)
        kx, ky = self.shape.curvature(s)
        rate, accel = ds / self.duration, dds / (self.duration * self.duration)  # ds/dt [1/s], d2s/dt2 [1/s^2]
        qd, qdd = kinematics.rates_2link(q1, q2, self.l1, self.l2, tx * rate, ty * rate,
                                         kx * rate * rate + tx * accel, ky * rate * rate + ty * accel)
        return [q1, q2, *self._rest], [*qd, *self._rest], [*qdd, *self._rest]

    def profile(self, points: int = 0) -> Profile:
        return tip_profile([self.shape], [self.duration], points or PATH_POINTS, self.l1, self.l2, self.elbow,
                            len(self._rest))


def line(lengths, elbow, n_joints, duration, start_mm, end_mm, name="line"):
    """A straight tip path from start_mm to end_mm [mm] with cubic time scaling."""
    (x0, y0), (x1, y1) = [(a * 1e-3, b * 1e-3) for a, b in (start_mm, end_mm)]
    return CartesianPath(name, Line((x0, y0), (x1, y1)), duration, lengths, elbow, n_joints)


def figure_eight(lengths, elbow, n_joints, duration, centre_mm=(40.0, 140.0), half_width_mm=30.0,
                 half_height_mm=25.0):
    """A figure-eight of the tip about centre_mm [mm] (not one of the thesis's paths: a test of
    generalisation), with cubic time scaling over the whole figure."""
    shape = FigureEight((centre_mm[0] * 1e-3, centre_mm[1] * 1e-3), half_width_mm * 1e-3, half_height_mm * 1e-3)
    return CartesianPath("figure_eight", shape, duration, lengths, elbow, n_joints)


def translation(lengths, elbow, n_joints, duration=15.0, start_mm=(70.0, 135.0), end_mm=(-20.0, 135.0)):
    """rig-facts §1 translation mode: (70, 135) -> (-20, 135) mm in 15 s."""
    return line(lengths, elbow, n_joints, duration, start_mm, end_mm, "translation")


def circle(lengths, elbow, n_joints, duration=20.0, centre_mm=(50.0, 138.0), radius_mm=35.0):
    """rig-facts §1 circular mode: centre (50, 138) mm, radius 35 mm, one revolution."""
    return CartesianPath("circle", Circle((centre_mm[0] * 1e-3, centre_mm[1] * 1e-3), radius_mm * 1e-3),
                         duration, lengths, elbow, n_joints)


class Segmented(Trajectory):
    """Segments one after another, segment k running from ``ends[k - 1]`` to ``ends[k]`` [s];
    the loop finds its segment by bisection, so a sample costs the same for 2 segments or 1000."""

    def __init__(self, durations: Sequence[float]):
        self.ends = array("d", itertools.accumulate(float(d) for d in durations))
        self.duration = self.ends[-1]

    def segment(self, t: float) -> tuple[int, float]:
        """The segment at t and the time into it (the last segment from its end on)."""
        k = min(bisect.bisect_right(self.ends, t), len(self.ends) - 1)
        return k, t - (self.ends[k - 1] if k else 0.0)


class Chain(Segmented):
    """Trajectories one after another (e.g. an approach move, then a path); ``approach_s``:
    where the approach ends and the path begins [s from the start], None if none."""

    def __init__(self, parts: Sequence[Trajectory], approach_s: float | None = None):
        self.parts = list(parts)
        self.approach_s = approach_s
        super().__init__([p.duration for p in self.parts])

    def sample(self, t: float) -> Sample:
        k, t = self.segment(t)
        return self.parts[k].sample(t)

    def profile(self, points: int = 0) -> Profile:
        return Profile.concatenate([p.profile(points) for p in self.parts], [0.0, *self.ends[:-1]])


def _points_per_segment(segments: int, default: int) -> int:
    return max(9, min(default, PROFILE_BUDGET // segments))


class JointWaypoints(Segmented):
    """Through joint-space points [rad], segment i (to point i + 1) taking durations[i] [s]
    with cubic time scaling: at rest at every point."""

    def __init__(self, points: Sequence[Sequence[float]], durations: Sequence[float]):
        super().__init__(durations)
        self.n = len(points[0])
        self.points = array("d", itertools.chain.from_iterable(points))
        self._k = -1
        self._move: JointMove | None = None

    def _point(self, i: int) -> list[float]:
        return list(self.points[i * self.n:(i + 1) * self.n])

    def sample(self, t: float) -> Sample:
        k, t = self.segment(t)
        if k != self._k:
            self._k, self._move = k, JointMove(self._point(k), self._point(k + 1), self.ends[k] - (self.ends[k - 1] if k else 0.0))
        return self._move.sample(t)

    def profile(self, points: int = 0) -> Profile:
        p = np.frombuffer(self.points, dtype=float).reshape(-1, self.n)
        T = np.diff(np.concatenate([[0.0], np.frombuffer(self.ends, dtype=float)]))[:, None, None]
        tau = np.linspace(0.0, 1.0, points or _points_per_segment(len(self.ends), MOVE_POINTS))
        s, ds, dds = (x[None, :, None] for x in cubic_array(tau))
        dq = (p[1:] - p[:-1])[:, None, :]
        starts = np.concatenate([[0.0], np.frombuffer(self.ends, dtype=float)[:-1]])[:, None]
        flat = [x.reshape(-1, self.n) for x in (p[:-1, None, :] + dq * s, dq * ds / T, dq * dds / T ** 2)]
        return Profile((starts + tau[None, :] * T[:, :, 0]).ravel(), *flat)


class CartesianWaypoints(Segmented):
    """Straight tip lines through points [m], each with its duration [s] and cubic time
    scaling: at rest at every point."""

    def __init__(self, lengths, elbow: int, n_joints: int, points: Sequence[Sequence[float]],
                 durations: Sequence[float]):
        super().__init__(durations)
        self.lengths, self.elbow, self.n_joints = tuple(lengths[:2]), elbow, n_joints
        self.points = array("d", itertools.chain.from_iterable(points))
        self._k = -1
        self._path: CartesianPath | None = None

    def _line(self, k: int) -> Line:
        p = self.points
        return Line((p[2 * k], p[2 * k + 1]), (p[2 * k + 2], p[2 * k + 3]))

    def sample(self, t: float) -> Sample:
        k, t = self.segment(t)
        if k != self._k:
            duration = self.ends[k] - (self.ends[k - 1] if k else 0.0)
            self._k = k
            self._path = CartesianPath(f"segment {k + 1}", self._line(k), duration, self.lengths, self.elbow,
                                       self.n_joints)
        return self._path.sample(t)

    def profile(self, points: int = 0) -> Profile:
        durations = np.diff(np.concatenate([[0.0], np.frombuffer(self.ends, dtype=float)]))
        shapes = [self._line(k) for k in range(len(self.ends))]
        return tip_profile(shapes, durations, points or _points_per_segment(len(shapes), PATH_POINTS),
                            *self.lengths, self.elbow, self.n_joints - 2)


def joint_waypoints(points: Sequence[Sequence[float]], durations: Sequence[float]) -> JointWaypoints:
    """Through joint-space points [rad], segment i (to point i + 1) taking durations[i] [s]."""
    return JointWaypoints(points, durations)


def cartesian_waypoints(lengths, elbow, n_joints, points_mm: Sequence[Sequence[float]],
                        durations: Sequence[float]) -> CartesianWaypoints:
    """Straight tip lines through points [mm], each with its duration [s] and cubic time scaling."""
    return CartesianWaypoints(lengths, elbow, n_joints, [(x * 1e-3, y * 1e-3) for x, y in points_mm], durations)


class Steps(Segmented):
    """A step sequence: jump to levels[i] [rad] and hold it for holds[i] [s], one after another."""

    scalable = False

    def __init__(self, levels: Sequence[Sequence[float]], holds: Sequence[float]):
        super().__init__(holds)
        self.n = len(levels[0])
        self.levels = array("d", itertools.chain.from_iterable(levels))
        self._zeros = [0.0] * self.n
        self._k = -1
        self._level: list[float] = []

    def sample(self, t: float) -> Sample:
        k = min(bisect.bisect_right(self.ends, t), len(self.ends) - 1)
        if k != self._k:
            self._k, self._level = k, list(self.levels[k * self.n:(k + 1) * self.n])
        return self._level, self._zeros, self._zeros

    def profile(self, points: int = 0) -> Profile:
        starts = np.concatenate([[0.0], np.frombuffer(self.ends, dtype=float)[:-1]])
        return Profile.at_rest(starts, np.frombuffer(self.levels, dtype=float).reshape(-1, self.n).copy())
