"""The pause between a path's approach and the path: the loop holds the path's start until
the arm has settled there, then starts the path's clock.

A path (``path``, ``waypoints``) runs after a cubic move to its start (the planner's
approach, :func:`daemon.planner.commands.after_approach`). A tracking loop lags a moving
reference, so when the approach's reference arrives the joints are still on their way: a
path started then begins with the approach's lag as its error (on the simulated rig PID's
1.3 deg on the middle joint, its worst of the whole translation). So at the approach's end
the loop samples the path's start and holds it, the trajectory's clock stopped, until every
joint has been within ``SETTLE_BAND_DEG`` of it (a linear joint: ``SETTLE_BAND_MM``) for
``SETTLE_S`` without a break, or for
at most ``SETTLE_MAX_S``; then the path runs from its first sample. Constant work a cycle
(one comparison per joint), and only during the wait.
"""
from __future__ import annotations

import math

SETTLE_BAND_DEG = 0.3  # every joint this close to the path's start [deg] ...
SETTLE_BAND_MM = 1.0  # ... a linear joint this close [mm] ...
SETTLE_S = 0.25  # ... for this long without a break [s] ...
SETTLE_MAX_S = 10.0  # ... or the path starts anyway after this wait [s] (an event says it did not settle)


class SettleGate:
    """The wait at ``at_s`` into a trajectory (its approach's end) for the joints to reach
    ``start`` [rad]: :meth:`waiting` once a cycle from then on, until it says the path may run."""

    def __init__(self, at_s: float, start, dt: float, units=()):
        """``units``: each joint's position unit, "rad" (default) or "m"."""
        self.at = at_s  # [s] from the trajectory's start
        self.start = list(start)  # the path's first sample [rad or m]
        self.units = tuple(units) or ("rad",) * len(self.start)
        self.bands = [math.radians(SETTLE_BAND_DEG) if u == "rad" else SETTLE_BAND_MM * 1e-3 for u in self.units]
        self.needed = max(int(round(SETTLE_S / dt)), 1)  # cycles in the band in a row
        self.limit = int(round(SETTLE_MAX_S / dt))  # cycles of waiting at most
        self.dt = dt
        self.in_band = 0
        self.waited = 0
        self.settled = False

    def waiting(self, angles) -> bool:
        """One cycle of the wait with the joints at ``angles`` [rad]: True while the path must
        still wait, False once it may run (settled, or the wait is up)."""
        for r, q, band in zip(self.start, angles, self.bands):
            if not -band <= r - q <= band:
                self.in_band = 0
                break
        else:
            self.in_band += 1
        self.waited += 1
        if self.in_band >= self.needed:
            self.settled = True
            return False
        return self.waited < self.limit

    def summary(self, angles) -> dict:
        """What the ``reference`` event ``settled`` says: how long the path waited, whether the
        joints settled, and each joint's error then: ``error_deg`` on a rig of rotary joints, else
        ``error``, each joint's in its unit (deg or mm)."""
        errors = [(r - q) * (180.0 / math.pi if u == "rad" else 1e3) for r, q, u in zip(self.start, angles, self.units)]
        key = "error_deg" if all(u == "rad" for u in self.units) else "error"
        return {"waited_s": self.waited * self.dt, "settled": self.settled, key: errors}
