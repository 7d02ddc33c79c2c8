"""A linear potentiometer (device kind ``linear_potentiometer``, the default position sensor of a
linear joint): wiper volts -> the joint's position [m], with plausibility.

Read ratiometrically, as the rotary RDC506 is (wiper / supply, so the track's resistance
tolerance cancels): ``x = position_at_zero + direction * mm_per_ratio * (ratio - zero_ratio)``,
``mm_per_ratio`` the track's electrical stroke (e.g. 225 mm for a conductive-plastic 225 mm
potentiometer). Calibrated at two known positions (:func:`two_point_calibration`), which fixes
zero and direction. A reading at a rail (a broken wiper or supply wire), with an implausible
supply, or beyond the joint's travel by more than ``plausible_margin_mm`` is a sensor fault and
gives NaN, never a position.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.devices import Ratiometric
from hal.schema import require


@dataclass(frozen=True)
class LinearPotentiometerConfig:
    """Channel and two-point calibration of one linear joint's potentiometer."""

    channel: str
    mm_per_ratio: float  # the track's electrical stroke: position change per unit of ratio [mm]
    position_at_zero_mm: float = 0.0  # the joint's position when the ratio equals zero_ratio [mm]
    zero_ratio: float = 0.0  # wiper/supply ratio at the calibration zero [-]
    direction: int = 1  # +1: the position grows with the ratio; -1: falls
    supply_channel: str = ""  # measured supply (ratiometric); empty: use supply_volts
    supply_volts: float = 5.0  # nominal supply when none is measured [V]
    rail_margin: float = 0.01  # a ratio this close to 0 or 1 is a disconnected or shorted wiper
    plausible_margin_mm: float = 5.0  # tolerance beyond the joint's limits before "implausible" [mm]
    device: str = "linear_potentiometer"

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(0 < self.mm_per_ratio <= 10_000, "mm_per_ratio", f"must be within (0, 10000] mm, got {self.mm_per_ratio}")
        require(0.0 <= self.zero_ratio <= 1.0, "zero_ratio", f"must be within [0, 1], got {self.zero_ratio}")
        require(self.direction in (1, -1), "direction", f"must be +1 or -1, got {self.direction}")
        require(self.supply_volts > 0, "supply_volts", f"must be > 0, got {self.supply_volts}")
        require(0.0 <= self.rail_margin < 0.5, "rail_margin", f"must be within [0, 0.5), got {self.rail_margin}")
        require(self.plausible_margin_mm >= 0, "plausible_margin_mm", "must be >= 0")


def two_point_calibration(ratio_a: float, position_a_mm: float, ratio_b: float, position_b_mm: float) -> dict:
    """Calibration keys (``position_at_zero_mm`` at ratio 0, ``mm_per_ratio``, ``direction``)
    from the ratios read at two known positions."""
    if ratio_a == ratio_b or position_a_mm == position_b_mm:
        raise ValueError("two-point calibration needs two distinct ratios and two distinct positions")
    slope = (position_b_mm - position_a_mm) / (ratio_b - ratio_a)
    return {"position_at_zero_mm": position_a_mm - slope * ratio_a, "zero_ratio": 0.0, "mm_per_ratio": abs(slope),
            "direction": 1 if slope > 0 else -1}


class LinearPotentiometer(Ratiometric):
    """One linear potentiometer's volts -> the joint's position [m] within ``[low, high]``."""

    Config = LinearPotentiometerConfig
    unit = "m"

    def __init__(self, config: LinearPotentiometerConfig, low_m: float, high_m: float):
        super().__init__(config)
        self.low, self.high = low_m, high_m
        self._gain = config.direction * config.mm_per_ratio * 1e-3  # [m per ratio]
        self._x0 = config.position_at_zero_mm * 1e-3 - self._gain * config.zero_ratio  # [m] at ratio 0
        margin = config.plausible_margin_mm * 1e-3
        self._lo, self._hi = low_m - margin, high_m + margin
        self._ratio_lo, self._ratio_hi = config.rail_margin, 1.0 - config.rail_margin
        self._supply_lo, self._supply_hi = 0.5 * config.supply_volts, 1.5 * config.supply_volts

    @classmethod
    def create(cls, config: LinearPotentiometerConfig, limits: tuple[float, float] = (-math.inf, math.inf)):
        return cls(config, *limits)

    def convert(self, volts: float, supply_volts: float) -> float:
        """Position [m], or NaN when the reading cannot be true (see :meth:`diagnose`)."""
        if not self._supply_lo < supply_volts < self._supply_hi:
            return math.nan
        ratio = volts / supply_volts
        if not self._ratio_lo < ratio < self._ratio_hi:
            return math.nan
        x = self._x0 + self._gain * ratio
        return x if self._lo <= x <= self._hi else math.nan

    def ratio_for(self, position_m: float) -> float:
        """The wiper/supply ratio this calibration expects at a position [m] (simulators, checks)."""
        return (position_m - self._x0) / self._gain

    def diagnose(self, volts: float, supply_volts: float) -> str | None:
        """Why a reading is implausible, in words; None when it is a valid position."""
        nominal = self.config.supply_volts
        if not self._supply_lo < supply_volts < self._supply_hi:
            return f"supply {supply_volts:.3f} V is implausible (nominal {nominal:.2f} V)"
        if not math.isfinite(volts):
            return f"reading {volts!r} is not a number"
        ratio = volts / supply_volts
        if not self._ratio_lo < ratio < self._ratio_hi:
            return f"wiper at the rail ({volts:.3f} V of {supply_volts:.3f} V): disconnected or shorted"
        x = self._x0 + self._gain * ratio
        if not self._lo <= x <= self._hi:
            return (f"position {x * 1e3:.1f} mm is outside the travel {self._lo * 1e3:.1f}..{self._hi * 1e3:.1f} mm "
                    f"(the limits and plausible_margin_mm)")
        return None
