"""Shadow runs: a candidate controller steps beside the active one on the same measurements
and references, its output is published but never applied, and it can then be committed.

The candidate is told each cycle what was really applied (``Controller.applied``), so a
model-based one keeps a true picture of the plant's input. The comparison kept here is the
difference candidate - active per joint [V]: its maximum and RMS over the run.
"""
from __future__ import annotations

import math

from controllers.base import Controller, JointState, Reference, check_output


class ShadowRun:
    def __init__(self, controller: Controller, n: int):
        self.controller = controller
        self.u: list[float] | None = None  # what it would have commanded this cycle [V]
        self.cycles = 0
        self.max_diff = [0.0] * n  # [V]
        self._sum_sq = [0.0] * n

    def step(self, state: JointState, reference: Reference, applied: list[float]) -> None:
        """One cycle beside the active controller; raises what the candidate raises, or
        ValueError for output that is not one finite value per joint."""
        u = self.controller.step(state, reference)
        check_output(u, len(applied))
        self.controller.applied(applied)
        self.u = list(u)
        self.cycles += 1
        for j, (a, b) in enumerate(zip(self.u, applied)):
            diff = abs(a - b)
            if diff > self.max_diff[j]:
                self.max_diff[j] = diff
            self._sum_sq[j] += diff * diff

    def summary(self) -> dict:
        return {"controller": self.controller.name, "cycles": self.cycles, "max_diff_volts": list(self.max_diff),
                "rms_diff_volts": [math.sqrt(s / self.cycles) if self.cycles else 0.0 for s in self._sum_sq]}
