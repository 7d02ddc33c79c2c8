"""The way back inside the joint limits: ``enable`` with a joint outside them.

Vented after a trip, a joint goes where its load takes it: on the simulated rig the identified
friction has no static holding, and the middle joint's spring draws it to its neutral angle,
-166 deg, 6 deg below its -160 deg limit (docs/simulator.md); a real arm sags under gravity
the same way. The limit rule would trip such an arm again in the cycle it was enabled. So
``enable`` allows a joint outside its limits on two conditions, and moves it back:

- the reference is a cubic move from where the arm is to ``RECOVER_MARGIN_DEG`` inside each
  limit a joint is beyond (the others hold), at a mean ``RECOVER_SPEED_DEG_S`` (at least
  ``RECOVER_MIN_S``): named ``recover``, it runs as any reference (motion commands wait for it;
  ``abort`` holds the arm where it is, and the time below still runs);
- the joint must not go further out than where it was enabled by more than
  ``RECOVER_SLACK_DEG``, and must be back inside, by ``RECOVER_INSIDE_DEG`` (so that sensor
  noise at the limit is no new excursion), within the move's time plus ``RECOVER_GRACE_S``;
  else it trips, saying which. Once inside, its limit rule is the usual one.

Constant work a cycle, one comparison per joint still outside, and only while one is.
"""
from __future__ import annotations

import math

RECOVER_MARGIN_DEG = 2.0  # the move's target: this far inside the limit [deg]
RECOVER_INSIDE_DEG = 1.0  # back inside once this far inside the limit [deg]
RECOVER_SPEED_DEG_S = 2.0  # the move's mean speed [deg/s] ...
RECOVER_MIN_S = 1.0  # ... and its shortest time [s]
RECOVER_GRACE_S = 3.0  # the joint back inside within the move's time plus this [s]
RECOVER_SLACK_DEG = 1.0  # further out than where it was enabled by more than this trips [deg]


class Recovery:
    """Joints enabled outside their limits (``limits`` [rad] per joint, the arm at ``angles``
    [rad]) on their way back, one cycle of ``dt`` [s] a :meth:`check`."""

    def __init__(self, names, limits, angles, dt: float):
        self.names = tuple(names)
        margin, slack = math.radians(RECOVER_MARGIN_DEG), math.radians(RECOVER_SLACK_DEG)
        inside = math.radians(RECOVER_INSIDE_DEG)
        self.targets = list(angles)  # the move's end [rad]
        # per joint outside: (its index, its angle when enabled, the angle beyond which it trips,
        # the angle past which it is back inside, +1 below its low limit / -1 above its high one)
        self.outside: list[tuple[int, float, float, float, float]] = []
        for j, (q, (lo, hi)) in enumerate(zip(angles, limits)):
            if lo <= q <= hi:
                continue
            middle = 0.5 * (lo + hi)
            if q < lo:
                self.targets[j] = min(lo + margin, middle)
                self.outside.append((j, q, q - slack, min(lo + inside, middle), 1.0))
            else:
                self.targets[j] = max(hi - margin, middle)
                self.outside.append((j, q, q + slack, max(hi - inside, middle), -1.0))
        farthest = max((abs(t - q) for t, q in zip(self.targets, angles)), default=0.0)
        self.move_s = max(RECOVER_MIN_S, math.degrees(farthest) / RECOVER_SPEED_DEG_S)  # [s]
        self.within_s = self.move_s + RECOVER_GRACE_S  # [s]
        self.limits = [(-math.inf, math.inf) if any(o[0] == j for o in self.outside) else lim
                       for j, lim in enumerate(limits)]  # the limit rule's, meanwhile: none for those outside
        self._limits = list(limits)
        self.dt = dt
        self.cycles = 0
        self._allowed = int(round(self.within_s / dt))  # cycles
        self.summary = self.describe()  # as it was enabled

    @property
    def finished(self) -> bool:
        """Every joint is back inside its limits."""
        return not self.outside

    def check(self, angles) -> str | None:
        """One cycle: the cause if a joint went further out or is not back in time, else None
        (a joint back inside leaves the recovery: its limit rule is the usual one again)."""
        self.cycles += 1
        late = self.cycles > self._allowed
        for k in range(len(self.outside) - 1, -1, -1):
            j, start, beyond, back, side = self.outside[k]
            q = angles[j]
            if (q - back) * side >= 0.0:  # inside, with the margin: done
                self.limits[j] = self._limits[j]
                del self.outside[k]
            elif (q - beyond) * side < 0.0:
                return (f"joint {self.names[j]} enabled outside its limits went further out: "
                        f"{math.degrees(q):.1f} deg, enabled at {math.degrees(start):.1f} deg "
                        f"(limits {self._degrees(j)})")
            elif late:
                return (f"joint {self.names[j]} enabled outside its limits is not back inside within "
                        f"{self.within_s:.1f} s: at {math.degrees(q):.1f} deg, enabled at "
                        f"{math.degrees(start):.1f} deg (limits {self._degrees(j)})")
        return None

    def _degrees(self, j: int) -> str:
        lo, hi = self._limits[j]
        return f"{math.degrees(lo):.1f}..{math.degrees(hi):.1f} deg"

    def describe(self) -> dict:
        """What the ``recover`` event and ``enable``'s reply say: each joint outside, where it
        is, its limits and the move's target [deg]; the move's time and the time allowed [s]."""
        return {"joints": {self.names[j]: {"angle_deg": math.degrees(start), "limits_deg": [
                    math.degrees(x) for x in self._limits[j]], "target_deg": math.degrees(self.targets[j])}
                           for j, start, *_ in self.outside},
                "move_s": self.move_s, "within_s": self.within_s}
