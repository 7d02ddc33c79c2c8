"""Hold: keep the output that was in force when it took over (no feedback)."""
from __future__ import annotations

from controllers.base import Controller, JointState, Reference


class Hold(Controller):
    """Holds the last output; the loop's fallback when a controller fails."""

    name = "hold"
    actuation = None  # any rig's: it repeats the output in force

    def __init__(self, context, **values):
        self._u = [0.0] * context.width
        super().__init__(context, **values)

    def reset(self, state: JointState, last_output) -> None:
        self._u = [float(u) for u in last_output]

    def step(self, state: JointState, reference: Reference) -> list[float]:
        return list(self._u)
