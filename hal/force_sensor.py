"""Asakusa Giken AS-FS tip force sensor behind its amplifier: volts -> newtons, with tare.

rig-facts §1: range 0-27.44 N. **Interpretation** (documented there): a linear amplifier,
``F = newtons_per_volt * (V - offset_volts) - tare``. A reading below zero force or above
the range by more than the margin is flagged: the former cannot be true (a disconnected
amplifier reads 0 V, which is below the offset), the latter means the sensor saturates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.devices import Sensor
from hal.schema import require

RANGE_N = 27.44


@dataclass(frozen=True)
class ForceSensorConfig:
    """Channel and linear calibration of the tip force sensor's amplifier."""

    channel: str
    newtons_per_volt: float = 6.86  # 27.44 N over 4 V of amplifier span [N/V]
    offset_volts: float = 0.5  # amplifier output at zero force [V]
    range_n: float = RANGE_N
    margin_n: float = 1.0  # tolerance outside 0..range before a reading is flagged [N]
    device: str = "asfs"

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(self.newtons_per_volt != 0, "newtons_per_volt", "must not be zero")
        require(0 < self.range_n <= 100 * RANGE_N, "range_n", f"must be > 0, got {self.range_n}")
        require(self.margin_n >= 0, "margin_n", "must be >= 0")


class ASFS(Sensor):
    """Converts amplifier volts to tip force [N]; :meth:`tare` zeroes the current load."""

    Config = ForceSensorConfig
    unit = "N"

    def __init__(self, config: ForceSensorConfig):
        super().__init__(config)
        self.low, self.high = 0.0, config.range_n
        self.tare_n = 0.0

    def raw_force(self, volts: float) -> float:
        """Force [N] from the calibration alone, before tare."""
        return self.config.newtons_per_volt * (volts - self.config.offset_volts)

    def convert(self, volts: float) -> float:
        """Tared force [N]; NaN when the reading cannot be trusted (:meth:`diagnose`)."""
        f, c = self.raw_force(volts), self.config
        return f - self.tare_n if -c.margin_n <= f <= c.range_n + c.margin_n else math.nan  # NaN fails both

    def volts_for(self, force_n: float) -> float:
        """Amplifier volts this calibration expects for a raw force (for simulators, checks)."""
        return self.config.offset_volts + force_n / self.config.newtons_per_volt

    def tare(self, volts: float) -> None:
        """Take the present raw force as zero (e.g. the mean of a still window)."""
        if self.diagnose(volts) is not None:
            raise ValueError(f"cannot tare on an implausible reading: {self.diagnose(volts)}")
        self.tare_n = self.raw_force(volts)

    def diagnose(self, volts: float) -> str | None:
        """Why a reading cannot be trusted, in words; None when it is in range."""
        if not math.isfinite(volts):
            return f"reading {volts!r} is not a number"
        f = self.raw_force(volts)
        if f < -self.config.margin_n:
            return f"force {f:.2f} N is below zero: amplifier disconnected or offset wrong"
        if f > self.config.range_n + self.config.margin_n:
            return f"force {f:.2f} N is over the sensor's {self.config.range_n} N range (saturated)"
        return None
