"""A known payload at the tip, fed forward: the V_MV each joint needs to hold the payload's
weight at a posture, added to whatever controller runs (rig-facts §4's model, §1's authority).

The payload (mass m [kg], centre of mass c [m] in the last link's frame, from the tip) adds
to joint i the torque dtau_i = m ((p_c - p_i) x g)_z [N m] (:func:`hal.kinematics.payload_torques`);
the cylinders balance it with -dtau_i, which is

    u_ff,i = -dtau_i / k_t,i                                                           [V]

of V_MV, k_t,i = K_mdl L A_H K_ep the joint's torque per volt (rig-facts §1 "Authority").
The loop evaluates it at the reference posture every cycle (a few products per joint, no
allocation beyond the result) and adds it to the controller's output, the controller's
output range shifted by it, so its anti-windup sees the saturation the plant sees.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hal.kinematics import payload_torques

MAX_COM_M = 0.5  # a centre of mass further than this from the tip is not a payload of this arm's [m]


@dataclass(frozen=True)
class KnownLoad:
    mass_kg: float
    com_m: tuple[float, float]  # along and across the last link, from the tip [m]
    lengths_m: tuple[float, ...]
    gravity_m_s2: tuple[float, float]
    volts_per_nm: tuple[float, ...]  # 1 / k_t per joint [V/(N m)]

    @classmethod
    def for_rig(cls, mass_kg: float, com_m: Sequence[float], context, lengths_m: Sequence[float],
                gravity_m_s2: Sequence[float]) -> "KnownLoad":
        """The load on a rig (its controller context: joint names, V_MV range, models), or
        ValueError: a joint with no model (its torque per volt unknown), or a load whose
        largest feed-forward, over every posture, would not fit the joint's V_MV range
        (bounded by m |g| (reach beyond the joint + |c|) / k_t, on the narrower side)."""
        if not (math.isfinite(mass_kg) and mass_kg > 0.0):
            raise ValueError(f"mass {mass_kg} kg: a load has a positive mass")
        if math.hypot(*com_m) > MAX_COM_M:
            raise ValueError(f"centre of mass {math.hypot(*com_m) * 1e3:.0f} mm from the tip: at most "
                             f"{MAX_COM_M * 1e3:.0f} mm")
        missing = [name for name, m in zip(context.joint_names, context.models or [None] * context.n) if m is None]
        if missing:
            raise ValueError(f"joint(s) {', '.join(missing)} have no identified model: their volts per N m "
                             f"are unknown (set [[joints]] model in the rig file)")
        g = math.hypot(*gravity_m_s2)
        for i, (name, model, lo, hi) in enumerate(zip(context.joint_names, context.models, context.u_min,
                                                        context.u_max)):
            worst = mass_kg * g * (sum(lengths_m[i:]) + math.hypot(*com_m)) / model.kt  # [V]
            if worst > min(-lo, hi):
                raise ValueError(f"a {mass_kg:g} kg load needs up to {worst:.2f} V of V_MV on joint {name}, beyond "
                                 f"its range {lo:+.2f}..{hi:+.2f} V: the arm cannot carry it everywhere")
        return cls(float(mass_kg), (float(com_m[0]), float(com_m[1])), tuple(lengths_m), tuple(gravity_m_s2),
                   tuple(1.0 / m.kt for m in context.models))

    def volts(self, angles: Sequence[float]) -> list[float]:
        """u_ff per joint [V] at joint angles [rad]."""
        torques = payload_torques(angles, self.lengths_m, self.mass_kg, self.com_m, self.gravity_m_s2)
        return [-t * k for t, k in zip(torques, self.volts_per_nm)]

    def volts_along(self, q: np.ndarray) -> np.ndarray:
        """u_ff [V] at each row of joint angles ``q`` [rad] (samples x joints), for the
        planner's feasibility check: the same model as :meth:`volts`, over arrays."""
        phi = np.cumsum(q, axis=1)
        x = np.cumsum(np.asarray(self.lengths_m) * np.cos(phi), axis=1)
        y = np.cumsum(np.asarray(self.lengths_m) * np.sin(phi), axis=1)
        px = np.hstack([np.zeros((len(q), 1)), x[:, :-1]])  # joint i's position
        py = np.hstack([np.zeros((len(q), 1)), y[:, :-1]])
        along, across = self.com_m
        cx = x[:, -1:] + along * np.cos(phi[:, -1:]) - across * np.sin(phi[:, -1:])
        cy = y[:, -1:] + along * np.sin(phi[:, -1:]) + across * np.cos(phi[:, -1:])
        gx, gy = self.gravity_m_s2
        torques = self.mass_kg * ((cx - px) * gy - (cy - py) * gx)
        return -torques * np.asarray(self.volts_per_nm)

    def describe(self) -> dict:
        return {"mass_kg": self.mass_kg, "com_mm": [c * 1e3 for c in self.com_m]}
