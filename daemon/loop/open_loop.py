"""The loop's side of an open-loop experiment (:class:`controllers.experiment.InputExperiment`):
constant work a cycle. While it settles, the excited joint's output is averaged; then that
joint's V_MV is the average plus the signal plus the slow centring PI (clamped to the V_MV
range), the controller's own output for it set aside; the joint leaving its band ends it at
once."""
from __future__ import annotations

import math

from controllers.experiment import InputExperiment


class OpenLoopRun:
    def __init__(self, experiment: InputExperiment, t0: float, joint_name: str):
        self.x, self.t0, self.name = experiment, t0, joint_name
        self.total, self.count = 0.0, 0
        self.u_op: float | None = None  # the operating point's V_MV [V], once settled
        self.integral = 0.0  # the centring PI's integral term [V]
        self.last_t = 0.0
        self.ended = ""  # why it ended: "done", or the band it left

    def apply(self, loop, now: float) -> bool:
        """Set this cycle's output of the excited joint (``loop.u``); False once it has ended."""
        x, j = self.x, self.x.joint
        t = now - self.t0
        if t < x.settle_s:
            self.total += loop.u[j]
            self.count += 1
            return True
        if self.u_op is None:
            self.u_op = self.total / self.count if self.count else loop.u[j]
            loop.events.add({"kind": "experiment", "action": "open_loop", "joint": self.name,
                             "u_op_v": self.u_op, "angle_deg": math.degrees(loop.angles[j])})
        if t >= x.duration:
            self.ended = "done"
            return False
        angle = loop.angles[j]
        if not x.band_lo <= angle <= x.band_hi:
            self.ended = (f"joint {self.name} at {math.degrees(angle):.1f} deg left its band "
                          f"{math.degrees(x.band_lo):.1f}..{math.degrees(x.band_hi):.1f} deg")
            return False
        lo, hi = loop.context.u_min[j], loop.context.u_max[j]
        error = x.angles[j] - angle  # [rad]
        if self.last_t:
            span = 0.5 * (hi - lo)  # the integral never asks for more than half the range
            i = self.integral + x.centre_ki * error * (t - self.last_t)
            self.integral = -span if i < -span else span if i > span else i
        self.last_t = t
        u = self.u_op + x.volts(t - x.settle_s) + x.centre_kp * error + self.integral
        loop.u[j] = lo if u < lo else hi if u > hi else u
        return True

    def tracking_reference(self, reference: list[float], angles) -> list[float]:
        """The reference the tracking rule judges: once open, the joint's own angle (no error)."""
        if self.u_op is None:
            return reference
        judged = list(reference)
        judged[self.x.joint] = angles[self.x.joint]
        return judged
