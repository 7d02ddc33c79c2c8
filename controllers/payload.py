"""Payload identification by torque balance (rig-facts §4): the mass and centre of mass of a
payload at the tip from the joint torques at static postures, loaded minus unloaded.

For a planar arm in the plane of gravity g [m/s^2] (the rig file's ``arm.gravity_m_s2``),
joint i at p_i, the tip at p_tip, and the payload's centre of mass at
p_c = p_tip + R(phi) c (c [m] in the last link's frame: along it and across it, phi the sum
of the joint angles), the payload adds to joint i the torque

    dtau_i = m ((p_c - p_i) x g)_z                                                  [N m]

which is linear in m and in m c. The paper's steps, decoupled:

1. **mass**: between two neighbouring joints the centre of mass cancels,
   dtau_i - dtau_(i+1) = m ((p_(i+1) - p_i) x g)_z: linear least squares in m over the
   postures (identifiable while a link between joints is not along gravity);
2. **centre of mass in the plane**: with m known, dtau_i / m - ((p_tip - p_i) x g)_z =
   c_along ((R e_x) x g)_z + c_across ((R e_y) x g)_z for every joint: linear least squares in
   c over the postures (identifiable when phi varies: the paper's 90 deg steps);
3. **out of the plane**: a planar arm's joint axes are all normal to the plane, so no moment
   about them depends on the payload's out-of-plane offset: **not identifiable** on this arm,
   and reported as such, never guessed.

Each step's 1-sigma comes from its residuals, s^2 (A^T A)^-1.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hal.kinematics import joint_points, moment, payload_torques

NOT_IDENTIFIABLE = "not identifiable on a planar arm: no joint axis sees an out-of-plane offset"


@dataclass(frozen=True)
class Posture:
    """One static posture: joint angles [rad], and the payload's torque per joint [N m]
    (loaded minus unloaded, at the same posture)."""

    angles_rad: tuple[float, ...]
    dtau_nm: tuple[float, ...]


@dataclass(frozen=True)
class PayloadEstimate:
    mass_kg: float
    mass_std_kg: float
    com_m: tuple[float, float]  # along and across the last link, from the tip [m]
    com_std_m: tuple[float, float]
    postures: int
    residual_nm: float  # RMS torque the identified payload leaves unexplained
    out_of_plane: str = NOT_IDENTIFIABLE

    def as_dict(self) -> dict:
        return {"mass_kg": self.mass_kg, "mass_std_kg": self.mass_std_kg, "com_mm": [c * 1e3 for c in self.com_m],
                "com_std_mm": [c * 1e3 for c in self.com_std_m], "postures": self.postures,
                "residual_nm": self.residual_nm, "out_of_plane": self.out_of_plane}


def _lstsq(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares with each coefficient's 1 sigma from the residuals."""
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    r = b - a @ x
    dof = max(len(b) - a.shape[1], 1)
    cov = np.linalg.pinv(a.T @ a) * float(r @ r) / dof
    return x, np.sqrt(np.clip(np.diag(cov), 0.0, None))


def identify(postures: Sequence[Posture], lengths: Sequence[float], gravity: Sequence[float]) -> PayloadEstimate:
    """The payload from ``postures`` (rows as above). ValueError when a step's regressor is
    rank-deficient (the postures cannot tell the unknowns apart: say which)."""
    if len(postures) < 2:
        raise ValueError(f"{len(postures)} posture(s): two at least are needed (the centre of mass has two unknowns)")
    rows_m, y_m, rows_c, y_c = [], [], [], []
    arms = [joint_points(p.angles_rad, lengths) for p in postures]  # joints and tip [m], per posture
    for p, points in zip(postures, arms):
        for i in range(len(points) - 2):  # step 1: neighbouring joints
            rows_m.append(moment((points[i + 1][0] - points[i][0], points[i + 1][1] - points[i][1]), gravity))
            y_m.append(p.dtau_nm[i] - p.dtau_nm[i + 1])
    a_m = np.array(rows_m)[:, None]
    if len(rows_m) == 0 or np.linalg.norm(a_m) < 1e-3 * math.hypot(*gravity) * max(lengths):
        raise ValueError("the mass is not identifiable from these postures: every link between joints lies "
                         "along gravity (or the arm has one joint)")
    mass, mass_std = _lstsq(a_m, np.array(y_m))
    m = float(mass[0])
    if m <= 0:
        raise ValueError(f"the torque differences give a mass of {m:.3g} kg: no payload, or the unloaded "
                         "reference is not this arm's")
    for p, points in zip(postures, arms):  # step 2: the centre of mass in the plane, every joint's row
        phi = sum(p.angles_rad)
        along, across = (math.cos(phi), math.sin(phi)), (-math.sin(phi), math.cos(phi))
        tip = points[-1]
        for i, q in enumerate(points[:-1]):
            rows_c.append([moment(along, gravity), moment(across, gravity)])
            y_c.append(p.dtau_nm[i] / m - moment((tip[0] - q[0], tip[1] - q[1]), gravity))
    a_c = np.array(rows_c)
    if np.linalg.matrix_rank(a_c, tol=1e-3 * float(np.abs(a_c).max() or 1.0)) < 2:
        raise ValueError("the centre of mass is not identifiable from these postures: the last link keeps one "
                         "direction; turn it (the paper's 90 deg steps)")
    com, com_std = _lstsq(a_c, np.array(y_c))
    model = [payload_torques(p.angles_rad, lengths, m, com, gravity) for p in postures]
    misfit = np.array([t - e for p, row in zip(postures, model) for t, e in zip(p.dtau_nm, row)])
    return PayloadEstimate(m, float(mass_std[0]), (float(com[0]), float(com[1])),
                           (float(com_std[0]), float(com_std[1])), len(postures),
                           float(np.sqrt(np.mean(misfit * misfit))))
