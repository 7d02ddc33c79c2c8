"""The simulated linear axes (rig-facts §5): each linear joint of the rig a
:class:`hal.axis_model.AxisModel`, driven by its 5/3 valve's volts, its position [m] from
the retracted end and its chamber pressures out. The parameters are the joint's
``[joints.linear_axis]`` (:class:`hal.linear_axis.AxisParams`), changed for the plant alone by
``[transport.options.joints.NAME] overrides`` (a plant off the nominal, as a controller meets
on a real rig); its ``sensor_offset_mm`` from ``fault_at_s`` of the plant's clock on is a
position sensor that drifted (what the model beside the axis is tested on, docs/model.md).
Turning the truth into sensor volts is the simulated transport's job.
"""
from __future__ import annotations

import dataclasses

from hal.config import RigConfig
from hal.errors import ConfigError
from hal.linear_axis import AxisParams
from hal.linear_axis_facts import rest_state
from hal.axis_model import AxisModel
from sim_backend.options import SimJointOptions, SimOptions


class SimAxisRig:
    """Every joint of a rig of linear joints, stepped together (they do not interact)."""

    def __init__(self, rig: RigConfig, options: SimOptions):
        unknown = sorted(set(options.joints) - {j.name for j in rig.joints})
        if unknown:
            raise ConfigError(f"transport.options.joints.{unknown[0]}: no joint of that name in the rig")
        self.joints: list[AxisModel] = []
        self._options: list[SimJointOptions] = []
        for j in rig.joints:
            jo = options.joints.get(j.name, SimJointOptions())
            jo.check_kind(j.name, linear=True)
            nominal = j.linear_axis or AxisParams()
            try:
                params = AxisParams.from_table({**dataclasses.asdict(nominal), **jo.overrides})
            except ConfigError as exc:
                raise ConfigError(f"transport.options.joints.{j.name}.overrides: {exc}") from None
            low, high = j.limits
            start = jo.initial_position_mm * 1e-3 if jo.initial_position_mm is not None else 0.5 * (low + high)
            try:
                state = rest_state(params, start)
            except ValueError as exc:
                raise ConfigError(f"transport.options.joints.{j.name}: {exc}") from None
            self.joints.append(AxisModel(params, options.step_s, state))
            self._options.append(jo)
        self.step_s, self.t = options.step_s, 0.0  # the plant's clock: its steps [s]
        self.disturbance_n = [0.0] * len(self.joints)  # external force per joint along +x [N]
        self.contact_force_n = 0.0  # no tip force sensor on an axis

    def position(self, joint: int) -> float:
        return self.joints[joint].position_m

    def sensed_position(self, joint: int) -> float:
        """What its sensor reads [m]: the position, plus a drifted offset (ramped in over ``offset_ramp_s``)."""
        jo = self._options[joint]
        if jo.sensor_offset_mm and self.t >= jo.fault_at_s:
            share = min((self.t - jo.fault_at_s) / jo.offset_ramp_s, 1.0) if jo.offset_ramp_s > 0 else 1.0
            return self.joints[joint].position_m + share * jo.sensor_offset_mm * 1e-3
        return self.joints[joint].position_m

    def chamber_gauge(self, joint: int, second: bool) -> float:
        """The head (or rod: ``second``) chamber's gauge pressure [Pa]."""
        m = self.joints[joint]
        return (m.p_rod_pa if second else m.p_head_pa) - m.params.atmosphere_pa

    @property
    def supply_pa(self) -> float:
        """The first axis's supply, gauge [Pa] (what a supply transmitter reads)."""
        m = self.joints[0]
        return m.supply_pa - m.params.atmosphere_pa

    @supply_pa.setter
    def supply_pa(self, gauge_pa: float) -> None:
        """Every axis's supply [Pa gauge]: 0 is a lost supply (the valve's supply port at the atmosphere)."""
        for m in self.joints:
            m.supply_pa = m.params.atmosphere_pa + gauge_pa

    def step(self, volts) -> None:
        """One plant step; ``volts`` holds each joint's valve command [V]."""
        for m, v, f in zip(self.joints, volts, self.disturbance_n):
            m.external_force_n = f
            m.step(v)
        self.t += self.step_s
