"""Planar serial-arm kinematics (rig-facts §1, [2-7] and [2-9..2-14]).

Angles in rad, lengths and positions in m. Joint i's angle is relative to link i-1, so the
tip is ``sum_i l_i * (cos, sin)(t_1 + ... + t_i)``.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def forward(angles: Sequence[float], lengths: Sequence[float]) -> tuple[float, float]:
    """Tip position (x, y) [m] for joint angles [rad] and link lengths [m], [2-7]."""
    x = y = phi = 0.0
    for q, l in zip(angles, lengths):
        phi += q
        x += l * math.cos(phi)
        y += l * math.sin(phi)
    return x, y


def jacobian(angles: Sequence[float], lengths: Sequence[float]) -> list[tuple[float, float]]:
    """Column i is d(tip)/d(angle_i) [m/rad]; joint torques from a tip force are J^T F."""
    phis, phi = [], 0.0
    for q in angles:
        phi += q
        phis.append(phi)
    columns = []
    for i in range(len(angles)):
        dx = -sum(l * math.sin(p) for l, p in zip(lengths[i:], phis[i:]))
        dy = sum(l * math.cos(p) for l, p in zip(lengths[i:], phis[i:]))
        columns.append((dx, dy))
    return columns


def rates_2link(q1: float, q2: float, l1: float, l2: float, vx: float, vy: float, ax: float,
                ay: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Joint rates [rad/s] and accelerations [rad/s^2] of a 2-link arm at angles (q1, q2) [rad]
    moving its tip at (vx, vy) [m/s] with acceleration (ax, ay) [m/s^2]: [2-7] differentiated
    once, v = J qd, and twice, a = J qdd + Jdot qd, solved by the 2x2 inverse. Written out, one
    sin/cos pair per angle: the loop calls it every cycle of a Cartesian path."""
    s1, c1, s12, c12 = math.sin(q1), math.cos(q1), math.sin(q1 + q2), math.cos(q1 + q2)
    b, d = -l2 * s12, l2 * c12  # J's columns (dx, dy) per joint: (a, c) the bottom's, (b, d) the middle's
    a, c = -l1 * s1 + b, l1 * c1 + d
    det = a * d - b * c
    w1, w2 = (d * vx - b * vy) / det, (-c * vx + a * vy) / det
    w12 = (w1 + w2) * (w1 + w2)
    ex = ax + l1 * c1 * w1 * w1 + l2 * c12 * w12  # a - Jdot qd: the centripetal terms moved across
    ey = ay + l1 * s1 * w1 * w1 + l2 * s12 * w12
    return (w1, w2), ((d * ex - b * ey) / det, (-c * ex + a * ey) / det)


def inverse_2link(x: float, y: float, l1: float, l2: float, elbow: int = -1) -> tuple[float, float]:
    """Joint angles [rad] reaching (x, y) [m] by the law of cosines [2-9..2-14].

    ``elbow`` picks the branch by the sign of the second angle; -1 is the branch on which the
    rig-facts speed figures for the reference paths were computed. Raises ValueError when
    the point is out of reach.
    """
    if elbow not in (1, -1):
        raise ValueError(f"elbow must be +1 or -1, got {elbow}")
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    if not -1.0 <= c2 <= 1.0:
        reach = math.hypot(x, y)
        raise ValueError(f"point ({_mm(x)}, {_mm(y)}) mm is out of reach "
                         f"({_mm(reach)} mm from the base; reach {abs(l1 - l2) * 1e3:.1f}..{(l1 + l2) * 1e3:.1f} mm)")
    t2 = elbow * math.acos(c2)
    t1 = math.atan2(y, x) - math.atan2(l2 * math.sin(t2), l1 + l2 * math.cos(t2))
    return t1, t2


def inverse_2link_array(x, y, l1: float, l2: float, elbow: int = -1):
    """:func:`inverse_2link` over numpy arrays of points [m]: (t1, t2) [rad], NaN where a
    point is out of reach (for the planner, which reports where)."""
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    c2 = np.where((c2 >= -1.0) & (c2 <= 1.0), c2, np.nan)
    t2 = elbow * np.arccos(c2)
    t1 = np.arctan2(y, x) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))
    return t1, t2


def joint_points(angles: Sequence[float], lengths: Sequence[float]) -> list[tuple[float, float]]:
    """Positions [m] of every joint and, last, the tip ([2-7], base joint at the origin)."""
    points, x, y, phi = [(0.0, 0.0)], 0.0, 0.0, 0.0
    for q, length in zip(angles, lengths):
        phi += q
        x, y = x + length * math.cos(phi), y + length * math.sin(phi)
        points.append((x, y))
    return points


def moment(r: tuple[float, float], g: Sequence[float]) -> float:
    """(r x g)_z [m^2/s^2]: the torque of a unit mass at r under g."""
    return r[0] * g[1] - r[1] * g[0]


def payload_torques(angles: Sequence[float], lengths: Sequence[float], mass_kg: float, com_m: Sequence[float],
                    gravity: Sequence[float]) -> list[float]:
    """The torque [N m] a payload of ``mass_kg`` at ``com_m`` (last link's frame: along it,
    across it, from the tip [m]) adds to each joint under ``gravity`` [m/s^2] in the arm's
    plane: dtau_i = m ((p_c - p_i) x g)_z (rig-facts §4). The simulator's truth and the
    payload identifier's model."""
    points = joint_points(angles, lengths)
    phi = sum(angles)
    tip = points[-1]
    c = (tip[0] + com_m[0] * math.cos(phi) - com_m[1] * math.sin(phi),
         tip[1] + com_m[0] * math.sin(phi) + com_m[1] * math.cos(phi))
    return [mass_kg * moment((c[0] - p[0], c[1] - p[1]), gravity) for p in points[:-1]]


def _mm(metres: float) -> str:
    """A distance [m] in mm for a refusal: 0.1 mm, or 3 significant digits past 1 km (a mistyped 1e308)."""
    return f"{metres * 1e3:.1f}" if abs(metres) < 1e3 else f"{metres * 1e3:.3g}"
