"""A pressure transmitter (device kind ``pressure_transmitter``): volts -> gauge pressure [Pa].
The muscle rig's valves each have one (rig-facts §2); a cylinder's chambers and the supply line
may have one too (``pressure_head``, ``pressure_rod``, ``[supply_pressure]``).

Linear: ``P = mpa_per_volt * (V - offset_volts)``, the defaults a 1-5 V sensor over
0-1 MPa. A reading more than ``margin_mpa`` outside 0..range cannot be true (a broken wire
reads 0 V, below the 1 V live zero) and is flagged, so the supervisor trips on it as on an
angle sensor's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.devices import Sensor
from hal.schema import require


@dataclass(frozen=True)
class PressureSensorConfig:
    channel: str
    mpa_per_volt: float = 0.25  # [MPa/V]
    offset_volts: float = 1.0  # output at 0 MPa gauge (a live zero) [V]
    range_mpa: float = 1.0
    margin_mpa: float = 0.05  # tolerance outside 0..range before a reading is flagged [MPa]
    device: str = "pressure_transmitter"

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(self.mpa_per_volt > 0, "mpa_per_volt", "must be > 0")
        require(0 < self.range_mpa <= 2.0, "range_mpa", "must be within (0, 2] MPa")
        require(self.margin_mpa >= 0, "margin_mpa", "must be >= 0")


class PressureSensor(Sensor):
    Config = PressureSensorConfig
    unit = "Pa"

    def __init__(self, config: PressureSensorConfig):
        super().__init__(config)
        self.low, self.high = 0.0, config.range_mpa * 1e6
        self._slope = config.mpa_per_volt * 1e6  # [Pa/V]
        self._low = -config.margin_mpa * 1e6
        self._high = (config.range_mpa + config.margin_mpa) * 1e6

    def convert(self, volts: float) -> float:
        """Gauge pressure [Pa]; NaN when the reading cannot be true (see :meth:`diagnose`)."""
        p = self._slope * (volts - self.config.offset_volts)
        return p if self._low <= p <= self._high else math.nan  # NaN fails both

    def volts_for(self, pressure_pa: float) -> float:
        """What this calibration reads for a pressure (the simulator's sensor)."""
        return self.config.offset_volts + pressure_pa / self._slope

    def diagnose(self, volts: float) -> str | None:
        if self.convert(volts) == self.convert(volts):  # not NaN: plausible
            return None
        if not math.isfinite(volts):
            return f"reading {volts!r} is not a number"
        p = self._slope * (volts - self.config.offset_volts) * 1e-6
        if p < 0:
            return f"{p:.3f} MPa is below zero: wire broken or offset wrong ({volts:.3f} V)"
        return f"{p:.3f} MPa is over the sensor's {self.config.range_mpa} MPa range ({volts:.3f} V)"
