"""Command interfaces: what a controller commands each joint with, and how that becomes the
joint's pressure pair (after ros2_control's command interfaces).

A joint declares its actuation by the devices its rig file names (:class:`hal.joints.JointConfig`):

- a **cylinder** joint takes one command, ``v_mv`` [V]: the manipulated variable of rig-facts §1
  [2-30..2-35]. The head chamber is commanded ``V_H = V_INI,H + V_MV``, the rod chamber held
  at ``V_L = V_INI,L``; the regulator line [2-29] turns those volts into chamber pressures [Pa].
  Its range is the regulator's 0-10 V less the bias, its top cut where the head pressure
  reaches the rig's ``[limits] max_pressure_mpa``: ``(p_max - offset) / slope - V_INI,H``
  (4 V bias, 0.7 MPa: -4..3.78 V; at the regulator's own 0.9 MPa, -4..6 V).
  The constant force due to the biases is an offset the controller's integral absorbs.
- a **muscle pair** joint (rig-facts §2) takes its two muscle pressures, ``pressure_a`` and
  ``pressure_b`` [Pa, gauge], and, where it has an MR brake, ``brake`` [N m].
- a **valve** joint (a 5/3 proportional directional valve, rig-facts §5) takes ``valve`` [V]
  about the valve's centre: the volts written are ``centre_volts + valve``
  (:mod:`hal.directional_valve`), over -centre..10 V - centre. Its neutral (what a controller
  starts from when the joint is enabled) is its safe command, so enabling is bumpless.

A controller's output is the flat vector of every joint's commands in joint order
(:attr:`RigActuation.commands`); on the cylinder rig that is one V_MV per joint.
"""
from __future__ import annotations

from collections.abc import Sequence

from hal.config import RigConfig
from hal.directional_valve import DirectionalValve
from hal.interfaces import CommandInterface
from hal.joints import CYLINDER, VALVE
from hal.regulator import V_MIN
from hal.rig import PressureDrivers
from hal.valve import ProportionalValve


class RigActuation:
    """The flat command vector of a rig -> each joint's (first, second) chamber pressure
    commands [Pa] and the direct commands (brake torques [N m], valve volts about the centre
    [V], in the order of :func:`hal.rig.direct_outputs`). Runs every cycle: plain lists, no
    allocation beyond the three it returns."""

    def __init__(self, rig: RigConfig, drivers: PressureDrivers | None = None):
        """``drivers``: the rig's pressure drivers when they are shared with its I/O
        (:mod:`daemon.assembly`); default: built here."""
        drivers = drivers or PressureDrivers.of(rig)
        commands: list[CommandInterface] = []
        self._cylinders = []  # (command index, joint index, head regulator, bias [V], rod pressure [Pa])
        self._muscles = []  # (command index, joint index)
        self._direct = []  # command index of each brake and valve, in joint order
        neutral = []
        p_limit = rig.limits.max_pressure_mpa * 1e6  # [Pa]
        for i, j in enumerate(rig.joints):
            k = len(commands)
            if j.actuation == VALVE:
                valve = DirectionalValve(j.valve)
                commands.append(CommandInterface(j.name, "valve", "V", valve.low, valve.high))
                neutral.append(valve.safe_volts - valve.centre)
                self._direct.append(k)
                continue
            if j.actuation == CYLINDER:
                head, rod = drivers.head[i], drivers.rod[i]  # the ITV0051 regulators
                bias = j.head.bias_volts
                # the V_MV whose head pressure the rig delivers: the regulator's span [2-29], cut at
                # [limits] max_pressure_mpa (hal.rig.RigIO.volts_for cuts the command there)
                commands.append(CommandInterface(j.name, "v_mv", "V", head.volts(0.0) - bias,
                                                 head.volts(p_limit) - bias))
                neutral.append(0.0)
                self._cylinders.append((k, i, head, bias, rod.bias_pa))
                continue
            p_max = min(rig.limits.max_pressure_mpa, j.valve_a.max_mpa, j.valve_b.max_mpa) * 1e6
            for side, valve in (("a", j.valve_a), ("b", j.valve_b)):
                commands.append(CommandInterface(j.name, f"pressure_{side}", "Pa",
                                                 ProportionalValve(valve).pressure(V_MIN), p_max))
            self._muscles.append((k, i))
            neutral += [0.0, 0.0]
            if j.brake is not None:
                self._direct.append(len(commands))
                commands.append(CommandInterface(j.name, "brake", "N m", 0.0, j.brake.max_nm))
                neutral.append(0.0)
        self.commands = tuple(commands)
        self.width = len(commands)
        self.n = len(rig.joints)
        self.u_min = tuple(c.low for c in commands)
        self.u_max = tuple(c.high for c in commands)
        self.neutral = tuple(neutral)  # the output a controller starts from when enabled

    def outputs(self, u: Sequence[float]) -> tuple[list[float], list[float], list[float]]:
        """(first chamber per joint, second chamber per joint) [Pa] (0 for a joint on a 5/3
        valve, which commands no pressure) and the direct commands (brakes [N m], valves [V])."""
        first, second = [0.0] * self.n, [0.0] * self.n
        for k, i, head, bias, rod_pa in self._cylinders:
            first[i], second[i] = head.pressure(bias + u[k]), rod_pa
        for k, i in self._muscles:
            first[i], second[i] = u[k], u[k + 1]
        return first, second, [u[k] for k in self._direct]

