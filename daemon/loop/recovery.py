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

A linear joint's figures are in mm (``RECOVER_MM``: margin, inside, speed in mm/s, slack), and
its messages and summary too (``position_mm``, ``limits_mm``, ``target_mm``).

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
RECOVER_MM = {"margin": 2.0, "inside": 1.0, "speed": 20.0, "slack": 1.0}  # a linear joint's [mm, mm/s]
_DEG = {"margin": RECOVER_MARGIN_DEG, "inside": RECOVER_INSIDE_DEG, "speed": RECOVER_SPEED_DEG_S,
        "slack": RECOVER_SLACK_DEG}
_SCALE = {"rad": (180.0 / math.pi, "deg"), "m": (1e3, "mm")}  # SI -> display, and its unit


class Recovery:
    """Joints enabled outside their limits (``limits`` [rad] per joint, the arm at ``angles``
    [rad]) on their way back, one cycle of ``dt`` [s] a :meth:`check`."""

    def __init__(self, names, limits, angles, dt: float, units=()):
        """``units``: each joint's position unit, "rad" (default) or "m"."""
        self.names = tuple(names)
        self.units = tuple(units) or ("rad",) * len(self.names)
        self.targets = list(angles)  # the move's end [rad or m]
        # per joint outside: (its index, its angle when enabled, the angle beyond which it trips,
        # the angle past which it is back inside, +1 below its low limit / -1 above its high one)
        self.outside: list[tuple[int, float, float, float, float]] = []
        move_s = 0.0
        for j, (q, (lo, hi)) in enumerate(zip(angles, limits)):
            if lo <= q <= hi:
                continue
            scale = _SCALE[self.units[j]][0]
            figures = _DEG if self.units[j] == "rad" else RECOVER_MM
            margin, slack, inside = (figures[k] / scale for k in ("margin", "slack", "inside"))
            middle = 0.5 * (lo + hi)
            if q < lo:
                self.targets[j] = min(lo + margin, middle)
                self.outside.append((j, q, q - slack, min(lo + inside, middle), 1.0))
            else:
                self.targets[j] = max(hi - margin, middle)
                self.outside.append((j, q, q + slack, max(hi - inside, middle), -1.0))
            move_s = max(move_s, abs(self.targets[j] - q) * scale / figures["speed"])
        self.move_s = max(RECOVER_MIN_S, move_s)  # [s]
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
                        f"{self._shown(j, q)}, enabled at {self._shown(j, start)} (limits {self._shown_limits(j)})")
            elif late:
                return (f"joint {self.names[j]} enabled outside its limits is not back inside within "
                        f"{self.within_s:.1f} s: at {self._shown(j, q)}, enabled at {self._shown(j, start)} "
                        f"(limits {self._shown_limits(j)})")
        return None

    def _shown(self, j: int, q: float) -> str:
        scale, unit = _SCALE[self.units[j]]
        return f"{q * scale:.1f} {unit}"

    def _shown_limits(self, j: int) -> str:
        scale, unit = _SCALE[self.units[j]]
        lo, hi = self._limits[j]
        return f"{lo * scale:.1f}..{hi * scale:.1f} {unit}"

    def describe(self) -> dict:
        """What the ``recover`` event and ``enable``'s reply say: each joint outside, where it
        is, its limits and the move's target (deg, or mm on a linear joint); the move's time and
        the time allowed [s]."""
        joints = {}
        for j, start, *_ in self.outside:
            scale, unit = _SCALE[self.units[j]]
            what = "angle" if unit == "deg" else "position"
            joints[self.names[j]] = {f"{what}_{unit}": start * scale, f"limits_{unit}": [x * scale for x in
                                                                                          self._limits[j]],
                                     f"target_{unit}": self.targets[j] * scale}
        return {"joints": joints, "move_s": self.move_s, "within_s": self.within_s}
