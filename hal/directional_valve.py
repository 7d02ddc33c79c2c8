"""A 5/3 proportional directional valve (the Festo MPYE kind: 0-10 V, the closed mid-position at
5 V) on one output channel: what a linear axis is driven with (rig-facts §5).

A controller commands it with ``valve`` [V] about the centre (``V = centre_volts + valve``): 0 is
the mid-position, positive opens supply to the head chamber and the rod chamber to exhaust
(the piston extends), negative the reverse (hal.linear_axis). The command is clamped to the
valve's 0-10 V; a non-finite one is refused, never written.

The safe state is ``safe_volts``, by default the centre: the valve's metering edges closed, the
chambers shut in and the piston held where it is (a vented cylinder would let a load drop or
coast). A real spool leaks at its centre, and on a differential cylinder (the head's area
larger than the rod side's) equal leaks leave a net force outwards: the piston may creep. A rig
file sets ``safe_volts`` to the valve's measured null where that matters (docs/rigs.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hal.errors import CommandError
from hal.schema import require

V_MIN, V_MAX = 0.0, 10.0  # the valve's command span [V]


@dataclass(frozen=True)
class DirectionalValveConfig:
    """``[joints.valve]``: the valve's output channel, its centre and its safe command."""

    channel: str
    centre_volts: float = 5.0  # the closed mid-position (MPYE catalogue: 5 V) [V]
    safe_volts: float | None = None  # written on every trip; default: the centre [V]

    def __post_init__(self):
        require(bool(self.channel), "channel", "must name a transport channel")
        require(V_MIN < self.centre_volts < V_MAX, "centre_volts", f"must be within ({V_MIN}, {V_MAX}) V")
        require(self.safe_volts is None or V_MIN <= self.safe_volts <= V_MAX, "safe_volts",
                f"must be within {V_MIN}-{V_MAX} V, got {self.safe_volts}")

    @property
    def safe(self) -> float:
        """The safe command [V]: ``safe_volts``, or the centre."""
        return self.centre_volts if self.safe_volts is None else self.safe_volts


class DirectionalValve:
    """The valve's command volts: pure, on the 1 ms path."""

    def __init__(self, config: DirectionalValveConfig):
        self.config = config
        self.centre = config.centre_volts
        self.low, self.high = V_MIN - config.centre_volts, V_MAX - config.centre_volts  # the command's range [V]
        self.safe_volts = config.safe

    def volts(self, command: float) -> float:
        """Output volts for a command about the centre [V], clamped to 0-10 V."""
        if not math.isfinite(command):
            raise CommandError(f"valve {self.config.channel}: non-finite command {command!r}")
        v = self.centre + command
        return V_MIN if v < V_MIN else V_MAX if v > V_MAX else v
