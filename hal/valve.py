"""Proportional solenoid valve with pressure feedback (the muscle rig's, rig-facts §2): set
pressure <-> command volts, linear over its calibrated span, clamped to its set range.

The valve regulates its outlet to ``offset_mpa + mpa_per_volt * V`` (gauge) for a command of
V volts within 0-10 V; the defaults are a 0-0.6 MPa valve (e.g. a Festo VPPM-6) driven 0-10 V.
Its dynamics (the valve and its line, [4.29]) are the simulator's business. Pa inside, volts at
the DAQ edge; a non-finite command is refused, never written.
"""
from __future__ import annotations

from dataclasses import dataclass

from hal.regulator import LinearPressureCommand
from hal.schema import require


@dataclass(frozen=True)
class ValveConfig:
    """One muscle's valve: its output channel and calibration."""

    channel: str
    mpa_per_volt: float = 0.06  # [MPa/V]
    offset_mpa: float = 0.0  # set pressure at 0 V [MPa]
    min_mpa: float = 0.0  # set range [MPa]
    max_mpa: float = 0.6
    safe_mpa: float = 0.0  # commanded on every trip: the muscle vents [MPa]

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(self.mpa_per_volt > 0, "mpa_per_volt", f"must be > 0, got {self.mpa_per_volt}")
        require(0 <= self.min_mpa < self.max_mpa <= 1.0, "max_mpa",
                f"set range must be within 0-1.0 MPa and not inverted: min {self.min_mpa}, max {self.max_mpa}")
        require(self.min_mpa <= self.safe_mpa <= self.max_mpa, "safe_mpa",
                f"must be within the set range {self.min_mpa}-{self.max_mpa} MPa, got {self.safe_mpa}")


class ProportionalValve(LinearPressureCommand):
    """Pure conversions for one valve (``volts`` is on the 1 ms path)."""

    kind = "valve"
