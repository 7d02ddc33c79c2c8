"""The simulated antagonistic artificial-muscle joint (rig-facts §2): valve commands in, the
arm's angle and the two sides' chamber pressures out.

Per side (muscle a, muscle b, ``per_side`` muscles in parallel on one valve):

- valve and line [4.29]: the set pressure the DAC asks for, delayed L = 0.040 s and passed
  through two lags T1 = T2 = 0.025 s, is the pressure at the line's end (limited by the supply);
- chamber [4.32..4.36]: the line feeds the muscles through a sonic conductance C (ISO 6358:
  ``m_dot = C rho0 p_up psi(p_down / p_up)``, psi = 1 when choked, below the critical ratio
  ``b_cr``), and the pressure of the ideal gas in the side's volume V(theta) follows
  ``dp/dt = kappa / V (R T m_dot - p dV/dt)`` (polytropic, kappa = 1.2);
- the muscles' force F(P, eps) of :mod:`hal.muscle` (Tondu & Lopez), on the pulley.

The arm: ``(J + m_L l^2) theta'' = tau_muscles + tau_gravity + tau_damping + tau_brake + tau_ext``,
the link and a tip load (0.168 kg at 240 mm, J = 4.80e-3 kg m^2 by default) under the rig's
gravity; damping ``-(D0 + eta K_m) omega`` (the rubber's loss grows with the pressures, as the
stiffness K_m does: **interpretation**, calibrated with the valve's conductance against the
chapter's settling times, docs/muscle-rig.md); the MR brake's torque opposes the motion and
holds the joint at rest up to its value (implicit Coulomb); mechanical stops beyond the
software limits. SI inside: rad, Pa (absolute in the gas law, gauge at the sensors), N m.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from hal.bounds import clip
from hal.config import RigConfig
from hal.errors import ConfigError
from hal.mr_brake import MRBrake
from hal.muscle import P_ATM, MuscleJoint
from hal.schema import require
from hal.valve import ProportionalValve

RHO0_RT = 1.185 * 287.0 * 293.15  # rho0 R T at ISO 6358's reference conditions [Pa]
SUBSTEPS = 4  # integration steps per plant step (1 ms): the stiffest arm mode is about 20 Hz


@dataclass(frozen=True)
class MusclePlantOptions:
    """``[transport.options.muscle]``: the simulated muscle joint's dynamics."""

    valve_lag_s: tuple[float, ...] = (0.025, 0.025)  # T1, T2 [4.29]
    valve_dead_time_s: float = 0.040  # L [4.29]
    conductance_m3_s_pa: float = 8e-9  # C, valve + line into one side's muscles (calibrated)
    critical_ratio: float = 0.3  # b_cr
    polytropic: float = 1.2  # kappa
    damping_nm_s: float = 0.005  # D0, the bearing's viscous damping [N m s/rad]
    stiffness_damping_s: float = 0.045  # eta: the muscles' damping per unit of their stiffness [s]
    tip_load_n: float = 0.0  # a weight hanging at the tip [N] (rig-facts §2: 0, 8.33, 16.66 N)
    force_scale: float = 1.0  # the true muscles' force over the rig file's model: a plant off the nominal

    def __post_init__(self):
        require(len(self.valve_lag_s) == 2 and all(0 < t <= 1 for t in self.valve_lag_s), "valve_lag_s",
                "two time constants within (0, 1] s")
        require(0 <= self.valve_dead_time_s <= 0.5, "valve_dead_time_s", "must be within 0-0.5 s")
        require(1e-12 <= self.conductance_m3_s_pa <= 1e-6, "conductance_m3_s_pa", "must be within 1e-12..1e-6")
        require(0 < self.critical_ratio < 1, "critical_ratio", "must be within (0, 1)")
        require(1.0 <= self.polytropic <= 1.4, "polytropic", "must be within 1.0-1.4")
        require(self.damping_nm_s >= 0 and self.stiffness_damping_s >= 0, "damping_nm_s", "must be >= 0")
        require(0 <= self.tip_load_n <= 200, "tip_load_n", "must be within 0-200 N")
        require(0.5 <= self.force_scale <= 1.5, "force_scale", "must be within 0.5-1.5")


class _Side:
    """One side's valve, line and chamber."""

    def __init__(self, valve: ProportionalValve, options: MusclePlantOptions, h: float, volume: float):
        self.valve = valve
        self.delay = deque([0.0] * max(int(round(options.valve_dead_time_s / h)), 1))
        self.lags = [math.exp(-h / t) for t in options.valve_lag_s]
        self.stage = [0.0, 0.0]  # the two lags' outputs [Pa gauge]
        self.p = P_ATM  # chamber [Pa abs]
        self.volume = volume

    def line_pressure(self, volts: float, supply_pa: float) -> float:
        """Advance the valve and line one plant step; the line's end [Pa abs]."""
        self.delay.append(self.valve.pressure(volts))
        x = self.delay.popleft()
        for k, a in enumerate(self.lags):
            self.stage[k] = a * self.stage[k] + (1.0 - a) * x
            x = self.stage[k]
        return P_ATM + clip(x, 0.0, max(supply_pa - 0.05e6, 0.0))


class MuscleJointSim:
    """One muscle-pair joint's state: ``th`` [deg] as the cylinder joints' (for the sensors)."""

    def __init__(self, model: MuscleJoint, valves, brake: MRBrake | None, options: MusclePlantOptions,
                 h: float, stops_rad: tuple[float, float], initial_rad: float):
        self.model, self.options, self.brake = model, options, brake
        self.h = h / SUBSTEPS
        self.stops = stops_rad
        self.theta, self.omega = initial_rad, 0.0
        volumes = self._volumes(initial_rad)
        self.sides = [_Side(v, options, h, vol) for v, vol in zip(valves, volumes)]
        self.tip_load_n = options.tip_load_n
        self.brake_nm = 0.0

    @property
    def th(self) -> float:
        return math.degrees(self.theta)

    def _volumes(self, theta: float) -> tuple[float, float]:
        pair = self.model.pair
        ea, eb = pair.contractions(theta)
        tube = pair.config.tube_volume_cm3 * 1e-6
        return pair.n * pair.volume(ea) + tube, pair.n * pair.volume(eb) + tube

    def gauge(self, side: int) -> float:
        return self.sides[side].p - P_ATM

    def step(self, volts_a: float, volts_b: float, brake_volts: float, supply_pa: float, external_nm: float) -> None:
        o, m = self.options, self.model
        lines = (self.sides[0].line_pressure(volts_a, supply_pa), self.sides[1].line_pressure(volts_b, supply_pa))
        self.brake_nm = self.brake.torque(brake_volts) if self.brake is not None else 0.0
        inertia = m.inertia_kg_m2 + m.tip_mass_kg(self.tip_load_n) * m.length_m ** 2
        h = self.h
        for _ in range(SUBSTEPS):
            volumes = self._volumes(self.theta)
            for side, line, v_new in zip(self.sides, lines, volumes):
                flow = _mass_flow(line, side.p, o.conductance_m3_s_pa, o.critical_ratio)  # [kg/s] x R T
                dv = (v_new - side.volume) / h
                side.p = max(side.p + h * o.polytropic / v_new * (flow - side.p * dv), 1000.0)
                side.volume = v_new
            pa, pb = self.sides[0].p - P_ATM, self.sides[1].p - P_ATM
            muscles = o.force_scale * m.pair.torque(pa, pb, self.theta)
            k_m = o.force_scale * m.pair.stiffness(pa, pb, self.theta)
            drive = muscles + m.gravity_torque(self.theta, self.tip_load_n) + external_nm
            damping = o.damping_nm_s + o.stiffness_damping_s * k_m
            w = (self.omega + h * drive / inertia) / (1.0 + h * damping / inertia)  # implicit damping
            hold = h * self.brake_nm / inertia  # implicit Coulomb: the brake stops what it can
            w = 0.0 if abs(w) <= hold else w - math.copysign(hold, w)
            theta = self.theta + h * w
            if theta < self.stops[0] or theta > self.stops[1]:
                theta, w = clip(theta, *self.stops), 0.0
            self.theta, self.omega = theta, w


def _mass_flow(p_up_line: float, p_chamber: float, conductance: float, b_cr: float) -> float:
    """ISO 6358 flow from the line into the chamber (negative: out), times R T [Pa m^3/s]."""
    if p_up_line >= p_chamber:
        up, down, sign = p_up_line, p_chamber, 1.0
    else:
        up, down, sign = p_chamber, p_up_line, -1.0
    r = down / up
    psi = 1.0 if r <= b_cr else math.sqrt(max(1.0 - ((r - b_cr) / (1.0 - b_cr)) ** 2, 0.0))
    return sign * conductance * RHO0_RT * up * psi


class SimMuscleRig:
    """The muscle rig as the simulated transport drives it: the same surface as
    :class:`sim_backend.plant.SimArm` (``step``, ``joints``, ``supply_pa``, ``disturbance_nm``)."""

    def __init__(self, rig: RigConfig, options):
        if len(rig.joints) != 1:
            raise ConfigError(f"joints: the simulated muscle rig is one joint (rig-facts §2), the rig file has "
                              f"{len(rig.joints)}")
        jc = rig.joints[0]
        muscle = options.muscle
        self.options = options
        self.supply_pa = options.supply_mpa * 1e6
        jo = options.joints.get(jc.name)
        margin = math.radians(jo.end_stop_margin_deg if jo is not None else 10.0)
        lo, hi = jc.limits_rad
        initial = jo.initial_angle_deg if jo is not None and jo.initial_angle_deg is not None else None
        model = MuscleJoint.from_rig(rig, jc)
        rest = math.radians(initial) if initial is not None else clip(_hanging(model), lo - margin, hi + margin)
        self.joint = MuscleJointSim(model, (ProportionalValve(jc.valve_a), ProportionalValve(jc.valve_b)),
                                    MRBrake(jc.brake) if jc.brake is not None else None, muscle, options.step_s,
                                    (lo - margin, hi + margin), rest)
        self.joints = [self.joint]
        self.has_brake = jc.brake is not None
        self.disturbance_nm = [0.0]
        self.contact_force_n = 0.0

    def position(self, joint: int) -> float:
        """The joint's angle [rad]."""
        return self.joint.theta

    sensed_position = position  # what its sensor reads: the position (no drift modelled here)

    def chamber_gauge(self, joint: int, side: int) -> float:
        return self.joint.gauge(side)

    def step(self, volts) -> None:
        """One plant step; ``volts`` is (valve a, valve b[, brake]) [V]."""
        self.joint.step(volts[0], volts[1], volts[2] if self.has_brake else 0.0, self.supply_pa,
                        self.disturbance_nm[0])


def _hanging(model: MuscleJoint) -> float:
    """Where gravity alone leaves the link [rad]: the angle gravity points along."""
    gx, gy = model.gravity_m_s2
    return math.atan2(gy, gx) if (gx or gy) else 0.0
