"""The simulated arm as a whole: joints, regulators, planar geometry, wall contact, force.

Inputs are the regulator command volts; outputs are true physical quantities (angles,
contact force). Turning those into sensor volts is the simulated transport's job.
"""
from __future__ import annotations

import math

from hal import kinematics
from hal.bounds import clip
from hal.config import RigConfig
from hal.errors import ConfigError
from hal.identified import (
    K_EP,
    P_OFFSET,
    P_SET_MAX,
    P_SET_MIN,
    SUPPLY_HEADROOM,
)
from hal.joint_model import JointModel
from sim_backend.options import SimJointOptions, SimOptions


def regulator_output(volts: float, supply_pa: float) -> float:
    """The pressure [Pa] an ITV0051 regulates to for a command [V], [2-29], limited by its
    supply (the set pressure needs supply + 0.1 MPa; with no supply the chamber exhausts)."""
    p = clip(K_EP * clip(volts, 0.0, 10.0) + P_OFFSET, P_SET_MIN, P_SET_MAX)
    ceiling = clip(supply_pa - SUPPLY_HEADROOM, 0.0, P_SET_MAX)
    return p if p < ceiling else ceiling


class SimArm:
    """All joints of the rig stepped together, with the tip contact coupling them."""

    def __init__(self, rig: RigConfig, options: SimOptions):
        self.options = options
        self.supply_pa = options.supply_mpa * 1e6
        self.lengths = rig.arm.link_lengths_m
        unknown = sorted(set(options.joints) - {j.name for j in rig.joints})
        if unknown:
            raise ConfigError(f"transport.options.joints.{unknown[0]}: no joint of that name in the rig")
        self.joints: list[JointModel] = []
        self._drifts: list[SimJointOptions | None] = []  # each joint's drift (docs/simulator.md "Drift")
        for jc in rig.joints:
            jo = options.joints.get(jc.name, SimJointOptions())
            jo.check_kind(jc.name, linear=False)
            model = jo.model or jc.model_name
            if model not in rig.joint_models:
                raise ConfigError(f"transport.options.joints.{jc.name}.model: no identified model {model!r} "
                                  f"(known: {', '.join(rig.joint_models)})")
            try:
                params = rig.joint_models[model].replace(jo.overrides)
            except (KeyError, ValueError) as exc:
                raise ConfigError(f"transport.options.joints.{jc.name}.overrides: {exc}") from None
            neutral = jo.neutral_angle_deg if jo.neutral_angle_deg is not None else jc.neutral_deg
            stops = (jc.min_angle_deg - jo.end_stop_margin_deg, jc.max_angle_deg + jo.end_stop_margin_deg)
            bias = (regulator_output(jc.head.bias_volts, self.supply_pa),
                    regulator_output(jc.rod.bias_volts, self.supply_pa))
            joint = JointModel(params, options.step_s, neutral, stops, initial_deg=neutral, initial_pset=bias,
                               friction=options.friction, dead_time=options.dead_time,
                               friction_model=options.friction_model)
            initial = jo.initial_angle_deg
            joint.th = min(max(initial if initial is not None else joint.equilibrium_deg(*bias), stops[0]), stops[1])
            self.joints.append(joint)
            self._drifts.append(jo if jo.drifts else None)
        self.t = 0.0  # the plant's clock: its steps [s]
        self._drifting = [False] * len(self.joints)  # each joint's drift has started
        self.disturbance_nm = [0.0] * len(self.joints)  # external torque per joint [N m]
        wall = options.wall
        norm = math.hypot(*wall.normal)
        self._wall = (wall.enabled, wall.point_mm[0] * 1e-3, wall.point_mm[1] * 1e-3,
                      wall.normal[0] / norm, wall.normal[1] / norm, wall.stiffness_n_per_mm * 1e3)
        self.contact_force_n = 0.0
        self._contact_torque = [0.0] * len(self.joints)
        self._no_load = [0.0] * len(self.joints)
        self._payload = (options.payload.mass_kg, tuple(c * 1e-3 for c in options.payload.com_mm),
                         tuple(rig.arm.gravity_m_s2))

    def position(self, joint: int) -> float:
        """Joint ``joint``'s angle [rad]."""
        return math.radians(self.joints[joint].th)

    def sensed_position(self, joint: int) -> float:
        """What joint ``joint``'s potentiometer reads [rad]: its angle, plus a drifted offset."""
        drift = self._drifts[joint]
        if drift is not None and self._drifting[joint]:
            ramp = drift.offset_ramp_s
            share = min((self.t - drift.fault_at_s) / ramp, 1.0) if ramp > 0 else 1.0
            return math.radians(self.joints[joint].th + share * drift.sensor_offset_deg)
        return self.position(joint)  # a subclass's own state (the compiled plant's arrays)

    def chamber_gauge(self, joint: int, second: bool) -> float:
        """The head (or rod: ``second``) chamber's pressure [Pa gauge], after the regulator's lag."""
        j = self.joints[joint]
        return j.p_rod if second else j.p_head

    def angles_rad(self) -> list[float]:
        return [math.radians(j.th) for j in self.joints]

    def tip_m(self) -> tuple[float, float]:
        return kinematics.forward(self.angles_rad(), self.lengths)

    def step(self, volts: list[float]) -> None:
        """One plant step; ``volts`` holds (head, rod) command volts per joint, flattened."""
        supply = self.supply_pa
        mass, com, gravity = self._payload
        load = kinematics.payload_torques(self.angles_rad(), self.lengths, mass, com, gravity) if mass else self._no_load
        for i, joint in enumerate(self.joints):
            head, rod = regulator_output(volts[2 * i], supply), regulator_output(volts[2 * i + 1], supply)
            drift = self._drifts[i]
            if drift is not None and self.t >= drift.fault_at_s:
                head, rod = self._drifted(i, drift, head, rod)
            joint.step(head, rod, self.disturbance_nm[i] + self._contact_torque[i] + load[i])
        self.t += self.options.step_s
        self._update_contact()

    def _drifted(self, i: int, drift: SimJointOptions, head: float, rod: float) -> tuple[float, float]:
        """Joint ``i``'s chamber set pressures [Pa] as its drifted regulators and a leaking
        chamber give them; its friction scaled once, at the drift's start."""
        if not self._drifting[i]:
            self._drifting[i] = True
            self.joints[i].scale_friction(drift.friction_scale)
        head, rod = head * drift.regulator_gain, rod * drift.regulator_gain
        if drift.leak == "head":  # the regulator's flow cannot make up the leak: the chamber settles below its set
            head *= 1.0 - drift.leak_fraction
        elif drift.leak == "rod":
            rod *= 1.0 - drift.leak_fraction
        return head, rod

    def _update_contact(self) -> None:
        """Penalty contact with the wall: F = k * penetration along the normal [N]; joint
        torques J^T F [N m] act on the next step."""
        enabled, px, py, nx, ny, k = self._wall
        if not enabled:
            return
        q = self.angles_rad()
        x, y = kinematics.forward(q, self.lengths)
        depth = -((x - px) * nx + (y - py) * ny)
        if depth <= 0.0:
            self.contact_force_n = 0.0
            self._contact_torque = [0.0] * len(self.joints)
            return
        f = k * depth
        self.contact_force_n = f
        self._contact_torque = [dx * f * nx + dy * f * ny for dx, dy in kinematics.jacobian(q, self.lengths)]
