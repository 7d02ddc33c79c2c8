"""An open-loop (input-side) identification experiment on one joint (rig-facts §1
"Experiments"): every joint's reference holds the operating point; after ``settle_s`` of
feedback holding it, the excited joint's controller is set aside and its V_MV is the mean
output of the settling time plus the signal [V], until the signal ends or the joint leaves
its band (then the loop holds it where it is, under feedback).

A held joint rests anywhere inside its static-friction band, so the mean output is the
equilibrium's only to within Fs / kt (0.3 V on the bottom joint, 1.7 V on the middle one),
and the slow spring turns that error into a drift of many degrees. A centring PI, far slower
than the signal (crossover ``centre_hz``, 0.03 Hz by default), pulls the joint back to its
operating point: it is the signal that makes the joint slide, so friction does not stall the
centring. Its output is part of the V_MV the recording holds, so the time-domain fit is
unaffected, and the frequency response is taken from the known signal (the joint
input-output method, :mod:`controllers.identification.frf`), which the centring does not bias.
The loop's side of it is :mod:`daemon.loop.open_loop`; :mod:`daemon.planner.excitation` builds and checks it.
"""
from __future__ import annotations

from collections.abc import Sequence

from controllers.signals import Excitation
from controllers.trajectory import Hold


class InputExperiment(Hold):
    """Hold ``base`` [rad]; ``signal`` (an Excitation on a one-joint base of 0) is in volts."""

    open_loop = True

    def __init__(self, base: Sequence[float], joint: int, signal: Excitation, settle_s: float,
                 band: tuple[float, float], definition: dict, centre_gains: tuple[float, float] = (0.0, 0.0)):
        super().__init__(base)
        self.joint, self.signal, self.settle_s = joint, signal, settle_s
        self.centre_kp, self.centre_ki = centre_gains  # [V/rad], [V/(rad s)]; 0, 0: pure open loop
        self.band_lo, self.band_hi = band  # [rad]
        self.duration = settle_s + signal.duration
        self.definition = definition  # the signal's settings, for the recording

    def volts(self, t: float) -> float:
        """The signal [V] at t [s] after the settling time."""
        return self.signal.offset(t)[0]
