"""A further analog input (device kind ``analog``, the default of ``[[inputs]]`` and
``[[joints.inputs]]``): any transducer with a linear output, ``value = per_volt * (V - offset)``
in the SI unit the table names, plausible within ``low..high``. A reading outside that range
(a broken wire on a live-zero transmitter reads 0 V) is a sensor fault and gives NaN.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.devices import Sensor
from hal.schema import require


@dataclass(frozen=True)
class AnalogInputConfig:
    """One analog input's channel, SI unit, linear calibration and plausible range."""

    channel: str
    unit: str  # SI (hal.devices.SI_UNITS): "Pa", "N", "K", "m" ...
    per_volt: float  # [unit/V]
    low: float  # plausible range [unit]
    high: float
    offset: float = 0.0  # the volts at a value of 0 [V]
    device: str = "analog"

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(self.per_volt != 0.0, "per_volt", "must not be zero")
        require(self.low < self.high, "high", f"the plausible range is inverted: low {self.low}, high {self.high}")


class AnalogInput(Sensor):
    Config = AnalogInputConfig

    def __init__(self, config: AnalogInputConfig):
        super().__init__(config)
        self.low, self.high = config.low, config.high

    def convert(self, volts: float) -> float:
        """The value [its unit]; NaN outside the plausible range."""
        c = self.config
        x = c.per_volt * (volts - c.offset)
        return x if c.low <= x <= c.high else math.nan  # NaN fails both

    def diagnose(self, volts: float) -> str | None:
        c = self.config
        if not math.isfinite(volts):
            return f"reading {volts!r} is not a number"
        x = c.per_volt * (volts - c.offset)
        if c.low <= x <= c.high:
            return None
        return f"{x:.4g} {c.unit} is outside its plausible {c.low:g}..{c.high:g} {c.unit} ({volts:.3f} V)"

    def volts_for(self, value: float) -> float:
        return self.config.offset + value / self.config.per_volt
