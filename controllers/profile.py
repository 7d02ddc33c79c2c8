"""Reference profiles, for the planner beside the loop: a reference's demands (angle, rate,
acceleration per joint) sampled along all of it as numpy arrays, and the checks that read
them. :meth:`controllers.trajectory.Trajectory.profile` builds one; the limit check here and
the authority check (:mod:`controllers.feasibility`) read it. Nothing here runs in the loop.

Angles in rad, rates in rad/s, accelerations in rad/s^2, positions in m, time in s. The tip
profile is the inverse kinematics of rig-facts §1 [2-9..2-14] and the Jacobian of [2-7].
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from hal import kinematics


class Profile(NamedTuple):
    """A reference's demands sampled along it at its own duration: times (N,) [s] and
    angles, rates, accelerations (N, joints) [rad, rad/s, rad/s^2]; NaN angles where a tip
    path leaves the arm's reach."""

    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    a: np.ndarray

    @classmethod
    def concatenate(cls, parts: Sequence["Profile"], offsets: Sequence[float]) -> "Profile":
        return cls(np.concatenate([p.t + o for p, o in zip(parts, offsets)]), *(
            np.concatenate([getattr(p, k) for p in parts]) for k in ("q", "w", "a")))

    @classmethod
    def at_rest(cls, t: np.ndarray, q: np.ndarray) -> "Profile":
        zeros = np.zeros_like(q)
        return cls(t, q, zeros, zeros)


def cubic_array(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cubic` over an array of tau in [0, 1]."""
    return 3 * tau ** 2 - 2 * tau ** 3, 6 * tau - 6 * tau ** 2, 6 - 12 * tau


class TipShape(ABC):
    """A planar tip path p(sigma) [m], sigma in [0, 1], its tangent dp/dsigma [m] and its
    second derivative d2p/dsigma2 [m]."""

    @abstractmethod
    def point(self, s: float) -> tuple[float, float]: ...

    @abstractmethod
    def tangent(self, s: float) -> tuple[float, float]: ...

    @abstractmethod
    def curvature(self, s: float) -> tuple[float, float]:
        """d2p/dsigma2 [m]: with the tangent, the tip's acceleration under the time scaling."""

    @abstractmethod
    def points(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """x, y, dx/ds, dy/ds over an array of sigma."""


def tip_profile(shapes: Sequence[TipShape], durations: Sequence[float], points: int, l1: float, l2: float,
                 elbow: int, rest: int) -> Profile:
    """The joint demands of tip shapes run one after another, each with cubic scaling over its
    duration: inverse kinematics [2-9..2-14], rates by the inverse Jacobian, accelerations by
    differences along each segment. NaN where a point is out of reach (or at a singularity)."""
    tau = np.linspace(0.0, 1.0, points)
    s, ds, _ = cubic_array(tau)
    T = np.asarray(durations, dtype=float)[:, None]  # (segments, 1)
    xs, ys, txs, tys = (np.stack(c) for c in zip(*(shape.points(s) for shape in shapes)))
    t = tau[None, :] * T
    vx, vy = txs * ds / T, tys * ds / T
    q1, q2 = kinematics.inverse_2link_array(xs, ys, l1, l2, elbow)
    # Jacobian columns [2-7]: d(x, y)/d(q1) and d(x, y)/d(q2)
    s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q1 + q2), np.cos(q1 + q2)
    a, c = -l1 * s1 - l2 * s12, l1 * c1 + l2 * c12
    b, d = -l2 * s12, l2 * c12
    det = a * d - b * c
    with np.errstate(divide="ignore", invalid="ignore"):
        w1, w2 = (d * vx - b * vy) / det, (-c * vx + a * vy) / det
        a1, a2 = (np.gradient(w, axis=1) / np.gradient(t, axis=1) for w in (w1, w2))
    offsets = np.concatenate([[0.0], np.cumsum(durations)[:-1]])[:, None]
    flat = [np.stack([x1.ravel(), x2.ravel(), *([np.zeros(x1.size)] * rest)], axis=1)
            for x1, x2 in ((q1, q2), (w1, w2), (a1, a2))]
    return Profile((t + offsets).ravel(), *flat)


def first_outside_limits(profile: Profile, limits: Sequence[tuple[float, float]], names: Sequence[str]) -> str | None:
    """Where the reference leaves the joint limits or the arm's reach, in words; None if nowhere."""
    q = profile.q
    lo, hi = np.array([lim[0] for lim in limits]), np.array([lim[1] for lim in limits])
    unreachable = np.isnan(q).any(axis=1)
    outside = unreachable | ((q < lo) | (q > hi)).any(axis=1)
    if not outside.any():
        return None
    i = int(np.argmax(outside))
    t = profile.t[i]
    if unreachable[i]:
        return f"the tip would leave the arm's reach at t = {t:.2f} s"
    j = int(np.argmax((q[i] < lo) | (q[i] > hi)))
    return (f"joint {names[j]} would reach {math.degrees(q[i, j]):.1f} deg at t = {t:.2f} s, outside its limits "
            f"{math.degrees(lo[j]):.1f}..{math.degrees(hi[j]):.1f} deg")
