"""The muscle joint's MR (magnetorheological) brake (rig-facts §2): braking torque [N m] <->
command volts of its coil driver.

An MR brake's torque grows with its coil current and opposes the motion; it cannot drive the
joint. **Interpretation** (the chapter gives no calibration): the driver's 0-10 V sets the
current linearly and the torque follows ``T = max_nm * (V / 10) ** exponent`` (1: linear,
2: quadratic in the current near zero, as the fluid's yield stress grows). Whether the
controller asks for a torque growing linearly or quadratically with speed (Fig. 4.25) is the
controller's choice, not the device's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.bounds import clip
from hal.errors import CommandError
from hal.schema import require

V_MAX = 10.0


@dataclass(frozen=True)
class BrakeConfig:
    channel: str
    max_nm: float = 2.0  # torque at 10 V [N m]
    exponent: float = 1.0  # T = max_nm (V/10)^exponent
    safe_nm: float = 0.0  # commanded on every trip [N m]

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(0 < self.max_nm <= 50, "max_nm", "must be within (0, 50] N m")
        require(0.5 <= self.exponent <= 3, "exponent", "must be within 0.5-3")
        require(0 <= self.safe_nm <= self.max_nm, "safe_nm", f"must be within 0-{self.max_nm} N m")


class MRBrake:
    def __init__(self, config: BrakeConfig):
        self.config = config
        self._inv = 1.0 / config.exponent

    def volts(self, torque_nm: float) -> float:
        """Coil command [V] for a braking torque [N m] (clamped to 0..max_nm)."""
        if not math.isfinite(torque_nm):
            raise CommandError(f"brake {self.config.channel}: non-finite torque command {torque_nm!r}")
        t = clip(torque_nm, 0.0, self.config.max_nm) / self.config.max_nm
        return V_MAX * t ** self._inv

    def torque(self, volts: float) -> float:
        """Braking torque [N m] a command of ``volts`` gives."""
        return self.config.max_nm * (clip(volts, 0.0, V_MAX) / V_MAX) ** self.config.exponent
