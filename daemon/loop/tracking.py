"""The supervisor's rule for a controller that has lost a joint (issue: controllers at the
rig's edges; after ros2_control's fallback controllers).

A joint whose tracking error |r - th| stays outside ``tracking_error_deg`` for
``tracking_window_s`` without closing in (the error now no smaller than when the window
began) is lost: a step or a large move that the joint is catching up on closes in and is
left alone; one pushed off, saturated the wrong way, or running away is not. The rule acts
long before the joint reaches its limits: at the authority's few deg/s a window of 2 s
costs a few degrees. Bounded work per cycle: one comparison per joint.
"""
from __future__ import annotations

import math


class TrackingGuard:
    """Watches the tracking error per joint while the arm is enabled; ``check`` says when a
    joint is lost and why (once per loss: it restarts after)."""

    def __init__(self, joint_names, bound_deg: float, window_s: float):
        self.names = tuple(joint_names)
        self.bound = math.radians(bound_deg)  # [rad]; 0: off
        self.window = window_s
        n = len(self.names)
        self._since = [math.nan] * n  # when the error left the band [s], NaN while inside
        self._at_start = [0.0] * n  # |error| when this window began [rad]

    def clear(self) -> None:
        """Forget every window (a new controller, a new enable)."""
        self._since = [math.nan] * len(self.names)

    def check(self, t: float, reference, angles) -> str | None:
        """The cause if a joint is lost at time ``t`` [s], else None."""
        if not self.bound:
            return None
        for j, (r, q) in enumerate(zip(reference, angles)):
            e = abs(r - q)
            if e <= self.bound:
                self._since[j] = math.nan
                continue
            since = self._since[j]
            if since != since:  # NaN: the error has just left the band
                self._since[j], self._at_start[j] = t, e
            elif t - since >= self.window:
                if e < self._at_start[j]:  # closing in: a new window from here
                    self._since[j], self._at_start[j] = t, e
                    continue
                self._since[j] = math.nan
                return (f"joint {self.names[j]} lost: tracking error {math.degrees(e):.1f} deg, outside "
                        f"{math.degrees(self.bound):g} deg for {self.window:g} s without closing in")
        return None
