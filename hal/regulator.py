"""SMC ITV0051-3MS electro-pneumatic regulator: chamber pressure <-> command volts.

rig-facts §1, [2-29]: ``P[MPa] = 0.0899 V + 0.001`` over 0-10 V, set range 0.001-0.9 MPa.
Pressures are in Pa (SI) on the software side and volts at the DAQ edge. Commands are
clamped to the regulator's range; a non-finite command is refused, never written.
A 0 V command vents the chamber; losing the regulator's 24 V supply does *not* guarantee
venting, so the safe state is a commanded pressure, not "power off".
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.bounds import clip
from hal.errors import CommandError
from hal.schema import require

PA_PER_MPA = 1.0e6
V_MIN, V_MAX = 0.0, 10.0  # the -3 variant's input span [V]


@dataclass(frozen=True)
class RegulatorConfig:
    """One regulator (one cylinder chamber): its output channel and calibration."""

    channel: str
    bias_volts: float = 4.0  # V_INI, the chamber's bias command [2-30..2-35] [V]
    safe_mpa: float = 0.001  # commanded on every trip; 0.001 MPa is 0 V, i.e. vent [MPa]
    mpa_per_volt: float = 0.0899  # [2-29] slope [MPa/V]
    offset_mpa: float = 0.001  # [2-29] pressure at 0 V [MPa]
    min_mpa: float = 0.001  # regulator set range [MPa]
    max_mpa: float = 0.9

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(self.mpa_per_volt > 0, "mpa_per_volt", f"must be > 0, got {self.mpa_per_volt}")
        require(0 <= self.min_mpa < self.max_mpa, "max_mpa",
                f"range inverted or negative: min {self.min_mpa}, max {self.max_mpa}")
        require(V_MIN <= self.bias_volts <= V_MAX, "bias_volts",
                f"must be within {V_MIN}-{V_MAX} V, got {self.bias_volts}")
        require(self.min_mpa <= self.safe_mpa <= self.max_mpa, "safe_mpa",
                f"must be within the set range {self.min_mpa}-{self.max_mpa} MPa, got {self.safe_mpa}")


class LinearPressureCommand:
    """A device that regulates to a set pressure linear in its 0-10 V command (this regulator,
    the muscle rig's proportional valve): pure conversions; ``volts`` is on the 1 ms path, so
    it is lean. The config names ``channel``, ``mpa_per_volt``, ``offset_mpa``, ``min_mpa``,
    ``max_mpa`` and ``safe_mpa``."""

    kind = "regulator"

    def __init__(self, config):
        self.config = config
        self._slope = config.mpa_per_volt * PA_PER_MPA  # [Pa/V]
        self._offset = config.offset_mpa * PA_PER_MPA  # [Pa]
        self._p_min = config.min_mpa * PA_PER_MPA
        self._p_max = config.max_mpa * PA_PER_MPA
        self.safe_volts = self.volts(config.safe_mpa * PA_PER_MPA)

    def volts(self, pressure_pa: float) -> float:
        """Command volts for a chamber pressure [Pa], clamped to the set range and 0-10 V."""
        if not math.isfinite(pressure_pa):
            raise CommandError(f"{self.kind} {self.config.channel}: non-finite pressure command {pressure_pa!r}")
        low, high = self._p_min, self._p_max  # hal.bounds.clip, inline: four of these run every cycle
        v = ((low if pressure_pa < low else high if pressure_pa > high else pressure_pa) - self._offset) / self._slope
        return V_MIN if v < V_MIN else V_MAX if v > V_MAX else v

    def pressure(self, volts: float) -> float:
        """Set pressure [Pa] that a command of ``volts`` asks for (the inverse of :meth:`volts`)."""
        return clip(self._slope * clip(volts, V_MIN, V_MAX) + self._offset, self._p_min, self._p_max)


class ITV0051(LinearPressureCommand):
    """One cylinder chamber's regulator, with the bias it is held at [2-30, 2-31]."""

    def __init__(self, config: RegulatorConfig):
        super().__init__(config)
        self.bias_pa = self.pressure(config.bias_volts)
