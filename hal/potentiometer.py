"""ALPS RDC506 rotary potentiometer: wiper volts -> joint angle (rad), with plausibility.

rig-facts §1: 320 deg effective travel, read ratiometrically (wiper / supply) so the wide
+-30 % resistance tolerance cancels; nominally ``angle = (ratio - 0.5) * 333.3 deg`` from the
index point, valid over +-160 deg. Each joint is calibrated at two known angles, which fixes
zero and direction. A reading at a rail, outside the electrical travel, with an implausible
supply, or beyond the joint's mechanical range is a sensor fault and gives NaN, never an angle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.devices import Ratiometric
from hal.schema import require

ELECTRICAL_HALF_TRAVEL_DEG = 160.0


@dataclass(frozen=True)
class PotentiometerConfig:
    """Channel and two-point calibration of one joint's potentiometer."""

    channel: str
    angle_at_zero_deg: float  # joint angle when the ratio equals zero_ratio [deg]
    zero_ratio: float = 0.5  # wiper/supply ratio at the calibration zero [-]
    deg_per_ratio: float = 333.3  # sensitivity [deg per unit ratio]
    direction: int = 1  # +1: angle grows with the ratio; -1: falls
    supply_channel: str = ""  # measured supply (ratiometric); empty: use supply_volts
    supply_volts: float = 5.0  # nominal supply when none is measured [V]
    rail_margin: float = 0.02  # a ratio this close to 0 or 1 is a disconnected/shorted wiper
    plausible_margin_deg: float = 15.0  # tolerance beyond the joint limits before "implausible"
    device: str = "rdc506"

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(self.direction in (1, -1), "direction", f"must be +1 or -1, got {self.direction}")
        require(self.deg_per_ratio > 0, "deg_per_ratio", f"must be > 0, got {self.deg_per_ratio}")
        require(0.0 < self.zero_ratio < 1.0, "zero_ratio", f"must be within (0, 1), got {self.zero_ratio}")
        require(self.supply_volts > 0, "supply_volts", f"must be > 0, got {self.supply_volts}")
        require(0.0 <= self.rail_margin < 0.5, "rail_margin", f"must be within [0, 0.5), got {self.rail_margin}")
        require(self.plausible_margin_deg >= 0, "plausible_margin_deg", "must be >= 0")


def two_point_calibration(ratio_a: float, angle_a_deg: float, ratio_b: float, angle_b_deg: float,
                          zero_ratio: float = 0.5) -> dict:
    """Calibration keys (``angle_at_zero_deg``, ``deg_per_ratio``, ``direction``) from two poses."""
    if ratio_a == ratio_b or angle_a_deg == angle_b_deg:
        raise ValueError("two-point calibration needs two distinct ratios and two distinct angles")
    slope = (angle_b_deg - angle_a_deg) / (ratio_b - ratio_a)
    return {
        "angle_at_zero_deg": angle_a_deg + slope * (zero_ratio - ratio_a),
        "zero_ratio": zero_ratio,
        "deg_per_ratio": abs(slope),
        "direction": 1 if slope > 0 else -1,
    }


class RDC506(Ratiometric):
    """Converts one potentiometer's volts to a joint angle within ``[min_rad, max_rad]``."""

    Config = PotentiometerConfig
    unit = "rad"

    def __init__(self, config: PotentiometerConfig, min_rad: float, max_rad: float):
        super().__init__(config)
        self.low, self.high = min_rad, max_rad
        self._gain = math.radians(config.direction * config.deg_per_ratio)  # [rad per ratio]
        self._angle0 = math.radians(config.angle_at_zero_deg)
        margin = math.radians(config.plausible_margin_deg)
        self._lo, self._hi = min_rad - margin, max_rad + margin
        self._ratio_lo, self._ratio_hi = config.rail_margin, 1.0 - config.rail_margin
        half = ELECTRICAL_HALF_TRAVEL_DEG / 333.3  # electrical travel as a ratio span about 0.5
        self._travel_lo, self._travel_hi = 0.5 - half, 0.5 + half

    @classmethod
    def create(cls, config: PotentiometerConfig, limits: tuple[float, float] = (-math.pi, math.pi)) -> "RDC506":
        return cls(config, *limits)

    def convert(self, volts: float, supply_volts: float) -> float:
        """Joint angle [rad], or NaN when the reading cannot be true (see :meth:`diagnose`)."""
        if not (0.5 * self.config.supply_volts < supply_volts < 1.5 * self.config.supply_volts):
            return math.nan
        ratio = volts / supply_volts
        if not (self._ratio_lo < ratio < self._ratio_hi and self._travel_lo <= ratio <= self._travel_hi):
            return math.nan
        a = self._angle0 + self._gain * (ratio - self.config.zero_ratio)
        return a if self._lo <= a <= self._hi else math.nan

    def ratio_for(self, angle_rad: float) -> float:
        """The wiper/supply ratio this calibration expects at ``angle_rad`` (for simulators, checks)."""
        return self.config.zero_ratio + (angle_rad - self._angle0) / self._gain

    def diagnose(self, volts: float, supply_volts: float) -> str | None:
        """Why a reading is implausible, in words; None when it is a valid angle."""
        nominal = self.config.supply_volts
        if not (0.5 * nominal < supply_volts < 1.5 * nominal):
            return f"supply {supply_volts:.3f} V is implausible (nominal {nominal:.2f} V)"
        if not math.isfinite(volts):
            return f"reading {volts!r} is not a number"
        ratio = volts / supply_volts
        if not (self._ratio_lo < ratio < self._ratio_hi):
            return f"wiper at the rail ({volts:.3f} V of {supply_volts:.3f} V): disconnected or shorted"
        if not (self._travel_lo <= ratio <= self._travel_hi):
            return f"wiper ratio {ratio:.3f} is outside the sensor's +-160 deg electrical travel"
        a = self._angle0 + self._gain * (ratio - self.config.zero_ratio)
        if not (self._lo <= a <= self._hi):
            return (f"angle {math.degrees(a):.1f} deg is outside the mechanical range "
                    f"{math.degrees(self._lo):.1f}..{math.degrees(self._hi):.1f} deg")
        return None
