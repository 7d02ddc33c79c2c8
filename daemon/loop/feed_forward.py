"""The loop's side of a known payload (controllers.known_load): its V_MV each cycle at the
reference posture, added to the controller's output, with the controller's output range
shifted by it so the sum stays in the V_MV range and anti-windup sees the plant's limits.
Bounded work per cycle: a few products per joint."""
from __future__ import annotations

from collections.abc import Sequence

from controllers.known_load import KnownLoad


class LoadFeedForward:
    def __init__(self, context):
        self.context = context
        self.load: KnownLoad | None = None
        self.volts = [0.0] * context.n  # this cycle's feed-forward per joint [V]

    def update(self, controller, angles: Sequence[float]) -> None:
        """The feed-forward at ``angles`` [rad], and ``controller``'s range shifted by it."""
        ff = self.volts = self.load.volts(angles)
        lo, hi, u_min, u_max = controller.u_lo, controller.u_hi, self.context.u_min, self.context.u_max
        for j, f in enumerate(ff):
            lo[j], hi[j] = u_min[j] - f, u_max[j] - f

    def added(self, u: Sequence[float]) -> list[float]:
        return [v + f for v, f in zip(u, self.volts)]

    def share(self, applied: Sequence[float]) -> list[float]:
        """The controller's part of the V_MV ``applied``: what a controller reset on it
        continues from, so the applied sum does not jump."""
        if self.load is None:  # (on a muscle rig, always: its commands are not one V_MV a joint)
            return list(applied)
        return [u - f for u, f in zip(applied, self.volts)]

    def change(self, load: KnownLoad | None, controller, angles: Sequence[float]) -> None:
        """Feed ``load`` forward from now (None: no load, and the controller's own range back)."""
        self.load = load
        if load is None:
            self.volts = [0.0] * self.context.n
            controller.u_lo[:], controller.u_hi[:] = self.context.u_min, self.context.u_max
        else:
            self.update(controller, angles)
