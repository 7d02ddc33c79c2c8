"""Test helpers: step-response figures (the simulated rig itself is :mod:`daemon.testing.simrig`)."""
from __future__ import annotations

import math

from bench import scenarios


def step_metrics(t, y, y0, step, t_step):
    """Overshoot [% of step] and 5 % settling time [s after t_step] of a step response."""
    pairs = [(ti - t_step, yi - y0) for ti, yi in zip(t, y) if ti >= t_step]
    result = scenarios.step_metrics([p[0] for p in pairs], [p[1] for p in pairs], step)
    return result.overshoot, result.settling


def deg(x: float) -> float:
    return math.degrees(x)
