"""An open-loop (input-side) identification experiment on one joint (rig-facts §1
"Experiments"): every joint's reference holds the operating point; after ``settle_s`` of
feedback holding it, the excited joint's feedback is set aside and its V_MV is the mean
output of the settling time plus the signal [V], until the signal ends or the joint leaves
its band (then the loop holds it where it is, under feedback). The loop's side of it is
:mod:`daemon.open_loop`; the planner builds and checks it (:func:`daemon.planner.plan_excite`).
"""
from __future__ import annotations

from collections.abc import Sequence

from controllers.signals import Excitation
from controllers.trajectory import Hold


class InputExperiment(Hold):
    """Hold ``base`` [rad]; ``signal`` (an Excitation on a one-joint base of 0) is in volts."""

    open_loop = True

    def __init__(self, base: Sequence[float], joint: int, signal: Excitation, settle_s: float,
                 band: tuple[float, float], definition: dict):
        super().__init__(base)
        self.joint, self.signal, self.settle_s = joint, signal, settle_s
        self.band_lo, self.band_hi = band  # [rad]
        self.duration = settle_s + signal.duration
        self.definition = definition  # the signal's settings, for the recording

    def volts(self, t: float) -> float:
        """The signal [V] at t [s] after the settling time."""
        return self.signal.offset(t)[0]
