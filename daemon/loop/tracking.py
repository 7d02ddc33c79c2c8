"""The supervisor's rule for a controller that has lost a joint (issue: controllers at the
rig's edges; after ros2_control's fallback controllers), and for a joint that does not move
at all while its reference does (issue 32: a stuck joint).

Two rules per joint, both O(1) per cycle (a handful of float operations on preallocated
per-joint lists; nothing grows with the path):

- **Lost.** A joint whose tracking error |r - th| stays outside ``tracking_error_deg`` for
  ``tracking_window_s`` without closing in (the error now no smaller than when the window
  began) is lost: a step or a large move that the joint is catching up on closes in and is
  left alone; one pushed off, saturated the wrong way, or running away is not. The rule acts
  long before the joint reaches its limits: at the authority's few deg/s a window of 2 s
  costs a few degrees.
- **Stuck.** The error rule misses a joint that never moves under a reference that sweeps
  back and forth (a circle): the error leaves the band for less than the window at a time.
  So the guard also weighs the joint's travel against its reference's: over each stretch of
  ``2 * tracking_error_deg`` of reference travel R = sum |dr| (a continuous move; a jump of
  more than half the band in one cycle is a step, left to the error rule), the joint's
  progress P = sum dth * sgn(dr) (its travel in the direction the reference last moved) must
  be at least R / 2. A joint within the band of a monotonic reference always passes
  (P >= R - band = R / 2); one following a sinusoid with gain g and phase lag phi makes
  P / R ~ g cos(phi); a stuck joint makes P ~ 0 (sensor noise telescopes: the sign changes
  only where the reference turns).
"""
from __future__ import annotations

import math

NAN = math.nan


class TrackingGuard:
    """Watches the tracking error and progress per joint while the arm is enabled; ``check``
    says when a joint is lost or stuck and why (once per finding: it restarts after)."""

    def __init__(self, joint_names, bound_deg: float, window_s: float):
        self.names = tuple(joint_names)
        self.bound = math.radians(bound_deg)  # [rad]; 0: off
        self.window = window_s  # [s]
        self.travel = 2.0 * self.bound  # reference travel per progress verdict [rad]
        self.jump = 0.5 * self.bound  # a reference change above this in one cycle is a step [rad]
        n = len(self.names)
        self._since = [NAN] * n  # when the error left the band [s], NaN while inside
        self._at_start = [0.0] * n  # |error| when this window began [rad]
        self._r = [NAN] * n  # last cycle's reference [rad], NaN: none yet
        self._q = [NAN] * n  # last cycle's angle [rad]
        self._sign = [0.0] * n  # direction the reference last moved (+1, -1; 0: not yet)
        self._ref_travel = [0.0] * n  # R [rad]
        self._progress = [0.0] * n  # P [rad]

    def clear(self) -> None:
        """Forget every window and every progress count (a new controller, a new enable)."""
        n = len(self.names)
        for j in range(n):
            self._since[j] = self._r[j] = self._q[j] = NAN
            self._sign[j] = self._ref_travel[j] = self._progress[j] = 0.0

    def check(self, t: float, reference, angles) -> str | None:
        """The cause if a joint is lost or stuck at time ``t`` [s], else None."""
        if not self.bound:
            return None
        bound, jump = self.bound, self.jump
        last_r, last_q, sign, ref_travel, progress = self._r, self._q, self._sign, self._ref_travel, self._progress
        for j, (r, q) in enumerate(zip(reference, angles)):
            # stuck: the joint's progress along its reference's travel (inline: this runs every cycle)
            r0, q0 = last_r[j], last_q[j]
            last_r[j], last_q[j] = r, q
            if r0 == r0:  # not NaN: a cycle since clear()
                dr = r - r0
                if dr > 0.0:
                    sign[j] = 1.0
                    if dr <= jump:
                        ref_travel[j] += dr
                elif dr < 0.0:
                    sign[j] = -1.0
                    if dr >= -jump:
                        ref_travel[j] -= dr
                progress[j] += (q - q0) * sign[j]
                if ref_travel[j] >= self.travel:
                    stuck = self._verdict(j)
                    if stuck is not None:
                        return stuck
            # lost: outside the band for the window without closing in
            e = r - q if r >= q else q - r
            if e <= bound:
                self._since[j] = NAN
                continue
            since = self._since[j]
            if since != since:  # NaN: the error has just left the band
                self._since[j], self._at_start[j] = t, e
            elif t - since >= self.window:
                if e < self._at_start[j]:  # closing in: a new window from here
                    self._since[j], self._at_start[j] = t, e
                    continue
                self._since[j] = NAN
                return (f"joint {self.names[j]} lost: tracking error {math.degrees(e):.1f} deg, outside "
                        f"{math.degrees(bound):g} deg for {self.window:g} s without closing in")
        return None

    def _verdict(self, j: int) -> str | None:
        """A stretch of reference travel is complete for joint ``j``: its cause if the joint
        made less than half that progress; the counts start again either way."""
        travel, progress = self._ref_travel[j], self._progress[j]
        self._ref_travel[j] = self._progress[j] = 0.0
        if progress >= 0.5 * travel:
            return None
        return (f"joint {self.names[j]} stuck: moved {math.degrees(progress):.1f} deg along a reference "
                f"that travelled {math.degrees(travel):.1f} deg (less than half)")
