"""The nominal joint model model-based controllers design against, in SI (rad, s, N m, V).

From rig-facts §1 "Identified joint model" [2-36..2-39, 2-43]: the table's J, D, K are per
degree (rig-facts "Units"), so they are multiplied by 180/pi here to act on radians:

    J th'' + D th' + K (th - th_0) = kt V_MV + tau_bias - tau_f(th'),   P_H lagged by T_ep,

with kt = K_mdl L A_H K_ep [N m/V] and tau_bias the torque of the two bias pressures. The
linear part in the state form of [2-43], x = [th, th', th''] [rad, rad/s, rad/s^2]:

    x' = A x + B V_MV,   A = [[0, 1, 0], [0, 0, 1], [-a0, -a1, -a2]],   B = [0, 0, b]^T
    a0 = K / (J T_ep), a1 = (D + K T_ep) / (J T_ep), a2 = (J + D T_ep) / (J T_ep), b = kt / (J T_ep)

followed by the input dead time T_dly. Constant terms (spring about th_0, bias torque) and
friction are left to the controllers' integral action or disturbance observer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hal.identified import JointParams
from hal.regulator import ITV0051

PER_DEG_TO_PER_RAD = 180.0 / math.pi


@dataclass(frozen=True)
class NominalJoint:
    J: float  # [N m s^2/rad]
    D: float  # [N m s/rad]
    K: float  # [N m/rad]
    kt: float  # torque per volt of V_MV [N m/V]
    T_ep: float  # regulator lag [s]
    T_dly: float  # input dead time [s]
    Fc: float  # Coulomb friction [N m]
    neutral: float  # th_0 [rad]
    bias_torque: float  # torque of the bias pressures on both chambers [N m]

    @classmethod
    def from_rig(cls, joint, p: JointParams | None) -> "NominalJoint | None":
        """The nominal model of one configured joint from its model set (the rig's
        ``joint_params``), or None when it has none."""
        if p is None:
            return None
        bias_head, bias_rod = ITV0051(joint.head).bias_pa, ITV0051(joint.rod).bias_pa  # the rig's calibration
        return cls(J=p.J * PER_DEG_TO_PER_RAD, D=p.D * PER_DEG_TO_PER_RAD, K=p.K * PER_DEG_TO_PER_RAD,
                   kt=p.torque_per_volt, T_ep=p.T_ep, T_dly=p.T_dly, Fc=p.Fc, neutral=math.radians(joint.neutral_deg),
                   bias_torque=p.K_mdl * p.L * (p.area_head * bias_head - p.area_rod * bias_rod))

    @property
    def input_offset(self) -> float:
        """The constant torques as V_MV [V]: the linear model of [2-43] on the absolute angle
        is driven by V_MV + input_offset, (bias torque + K th_0) / kt."""
        return (self.bias_torque + self.K * self.neutral) / self.kt

    def delay_steps(self, dt: float) -> int:
        """The dead time in whole loop periods."""
        return max(int(round(self.T_dly / dt)), 0)

    def state_space(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of [2-43] for x = [th, th', th'']; B per volt of V_MV."""
        jt = self.J * self.T_ep
        a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
                      [-self.K / jt, -(self.D + self.K * self.T_ep) / jt, -(self.J + self.D * self.T_ep) / jt]])
        return a, np.array([[0.0], [0.0], [self.kt / jt]])

    def static_torque(self, angle: float, velocity: float, acceleration: float) -> float:
        """Torque the cylinder must add beyond the bias to move so [N m] (regulator lag aside)."""
        friction = math.copysign(self.Fc, velocity) if velocity else 0.0
        return (self.J * acceleration + self.D * velocity + self.K * (angle - self.neutral) + friction
                - self.bias_torque)

    def static_volts(self, angle: float, velocity: float, acceleration: float) -> float:
        """V_MV that holds this motion in steady state [V]."""
        return self.static_torque(angle, velocity, acceleration) / self.kt

    def top_speed(self, angle: float, volts: float) -> float:
        """Steady speed [rad/s] at V_MV = volts at this angle, viscous term, spring and Coulomb
        friction all taking their share (rig-facts §1 "Authority that follows"); 0 if stuck."""
        drive = self.kt * volts + self.bias_torque - self.K * (angle - self.neutral)
        return math.copysign(max(abs(drive) - self.Fc, 0.0) / self.D, drive)
