"""The supervisor's rule for a controller that has lost a joint (after ros2_control's fallback
controllers), and for a joint that does not move at all while its reference does (a stuck
joint).

Two rules per joint, both O(1) per cycle (a handful of float operations on preallocated
per-joint lists; nothing grows with the path):

- **Lost.** A joint whose tracking error |r - th| stays outside ``tracking_error_deg`` (a linear
  joint's: ``tracking_error_mm``) for
  ``tracking_window_s`` without closing in (the error now no smaller than when the window
  began) is lost: a step or a large move that the joint is catching up on closes in and is
  left alone; one pushed off, saturated the wrong way, or running away is not. The rule acts
  long before the joint reaches its limits: at the authority's few deg/s a window of 2 s
  costs a few degrees.
- **Stuck.** The error rule misses a joint that never moves under a reference that sweeps
  back and forth (a circle, a chirp): the error leaves the band for less than the window at
  a time. So the guard also weighs how far the joint travels against how far its reference
  does, each through a play (backlash) operator of width ``NOISE_PLAY_DEG`` (Krasnosel'skii
  and Pokrovskii's play: the output moves only when the input pushes it from one side of the
  gap; sensor noise narrower than the gap adds nothing, however long it lasts). Over each
  stretch of ``2 * tracking_error_deg`` of reference travel R (a continuous move; a jump of
  more than half the band in one cycle is a step, carried through the play uncounted and left
  to the error rule), the joint's travel Q must be at least ``FOLLOW_FRACTION`` of R. Travel is
  blind to phase: over any half period a sinusoid of amplitude a travels 2a whatever its
  phase, so a loop that follows a sweep with gain g and any lag makes Q / R ~ g (the play
  takes b/2 off each amplitude: (g a - b/2) / (a - b/2)); a seized joint makes Q ~ 0. The
  thesis's 0.1-1 Hz chirp under PID keeps Q / R above 0.49 on the simulated rig (the middle
  joint at 1 deg and 1 Hz); a lag read as lack of progress, as a signed progress count did,
  tripped it at 0.6-0.68 Hz.
"""
from __future__ import annotations

import math

NAN = math.nan
NOISE_PLAY_DEG = 0.5  # the play's width [deg]: motion narrower than this is sensor noise, not travel
NOISE_PLAY_MM = 0.5  # on a linear joint [mm]
SHOWN = {"rad": ("deg", 180.0 / math.pi), "m": ("mm", 1000.0)}  # how a cause states an error
FOLLOW_FRACTION = 0.25  # a joint that travels less than this share of its reference's travel is stuck


class TrackingGuard:
    """Watches the tracking error and the travel per joint while the arm is enabled; ``check``
    says when a joint is lost or stuck and why (once per finding: it restarts after)."""

    def __init__(self, joint_names, bound_deg: float, window_s: float, bound_mm: float = 0.0, units=()):
        """``units``: each joint's position unit, "rad" (default) or "m" (a linear joint, whose
        band is ``bound_mm``)."""
        self.names = tuple(joint_names)
        n = len(self.names)
        self.units = tuple(units) or ("rad",) * n
        self.bounds = [math.radians(bound_deg) if u == "rad" else bound_mm * 1e-3 for u in self.units]  # [SI]; 0: off
        self.window = window_s  # [s]
        self.travels = [2.0 * b for b in self.bounds]  # reference travel per verdict [SI]
        self.jumps = [0.5 * b for b in self.bounds]  # a reference change above this in one cycle is a step [SI]
        self.half_plays = [0.5 * (math.radians(NOISE_PLAY_DEG) if u == "rad" else NOISE_PLAY_MM * 1e-3)
                           for u in self.units]  # [SI]
        self.on = any(self.bounds)
        self._since = [NAN] * n  # when the error left the band [s], NaN while inside
        self._at_start = [0.0] * n  # |error| when this window began [rad]
        self._r = [NAN] * n  # last cycle's reference [rad], NaN: none yet
        self._r_play = [0.0] * n  # the reference's play output [rad]
        self._q_play = [0.0] * n  # the joint's play output [rad]
        self._ref_travel = [0.0] * n  # R [rad]
        self._travel = [0.0] * n  # Q [rad]

    def clear(self) -> None:
        """Forget every window and every travel count (a new controller, a new enable)."""
        n = len(self.names)
        for j in range(n):
            self._since[j] = self._r[j] = NAN
            self._ref_travel[j] = self._travel[j] = 0.0

    def check(self, t: float, reference, angles) -> str | None:
        """The cause if a joint is lost or stuck at time ``t`` [s], else None."""
        if not self.on:
            return None
        bounds, jumps, plays = self.bounds, self.jumps, self.half_plays
        last_r, r_play, q_play, ref_travel, travel = self._r, self._r_play, self._q_play, self._ref_travel, self._travel
        for j, (r, q) in enumerate(zip(reference, angles)):
            bound, jump, h = bounds[j], jumps[j], plays[j]
            if not bound:
                continue
            # stuck: the joint's travel against its reference's, each through the play (inline:
            # this runs every cycle)
            r0 = last_r[j]
            last_r[j] = r
            if r0 != r0:  # NaN: the first cycle since clear(): both plays start centred
                r_play[j], q_play[j] = r, q
            else:
                dr = r - r0
                if -jump <= dr <= jump:
                    y = r_play[j]
                    if r > y + h:
                        ref_travel[j] += r - h - y
                        r_play[j] = r - h
                    elif r < y - h:
                        ref_travel[j] += y - h - r
                        r_play[j] = r + h
                else:  # a step: carried through the play, not counted
                    r_play[j] += dr
                y = q_play[j]
                if q > y + h:
                    travel[j] += q - h - y
                    q_play[j] = q - h
                elif q < y - h:
                    travel[j] += y - h - q
                    q_play[j] = q + h
                if ref_travel[j] >= self.travels[j]:
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
                unit, scale = SHOWN[self.units[j]]
                return (f"joint {self.names[j]} lost: tracking error {e * scale:.1f} {unit}, outside "
                        f"{bound * scale:g} {unit} for {self.window:g} s without closing in")
        return None

    def _verdict(self, j: int) -> str | None:
        """A stretch of reference travel is complete for joint ``j``: its cause if the joint
        travelled less than FOLLOW_FRACTION of it; the counts start again either way."""
        ref_travel, travel = self._ref_travel[j], self._travel[j]
        self._ref_travel[j] = self._travel[j] = 0.0
        if travel >= FOLLOW_FRACTION * ref_travel:
            return None
        unit, scale = SHOWN[self.units[j]]
        return (f"joint {self.names[j]} stuck: moved {travel * scale:.1f} {unit} while its reference travelled "
                f"{ref_travel * scale:.1f} {unit} (less than {FOLLOW_FRACTION:.0%} of it)")
