"""A first-order low-pass for the controllers that act on the raw angle (PID, LTI) and for
the disturbance observer's estimate: the rig's sensor noise (0.03 deg on the simulated rig)
would otherwise reach the valves through the proportional gain as tens of volts per second
of output motion (docs/controllers.md, "Robustness").

    y[k] = y[k-1] + a (x[k] - y[k-1]),   a = 1 - exp(-2 pi f_c h),

the exact discretisation of 1/(s/(2 pi f_c) + 1) at the loop period h; f_c = 0 passes x
(a = 1). At the 20 Hz default its lag at the bottom joint's 0.6 Hz crossover is 1.7 deg.
"""
from __future__ import annotations

import math

from controllers.base import ParamSpec


def smoothing_param(name: str, what: str, default_hz: float = 20.0) -> ParamSpec:
    return ParamSpec(name, "Hz", 0.0, 500.0, (default_hz, default_hz), f"first-order low-pass on {what} (0: none)")


def smoothing_gains(cutoff_hz, dt: float) -> tuple[float, ...]:
    """The update gain a per joint for cut-offs [Hz] at the loop period dt [s]."""
    return tuple(1.0 - math.exp(-2.0 * math.pi * f * dt) if f > 0 else 1.0 for f in cutoff_hz)
