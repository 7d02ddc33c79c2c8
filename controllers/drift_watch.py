"""Every watched joint of a rig beside the arm (docs/model.md): which joints a model runs beside,
and the watch that feeds each its rows of the ``state`` messages and judges them: a rotary
cylinder joint's :class:`controllers.drift.JointWatch`, a linear axis's
:class:`controllers.drift_axis.AxisWatch`."""
from __future__ import annotations

import math

from controllers.drift import JointWatch, Verdict
from controllers.drift_axis import AxisWatch
from hal.config import RigConfig
from hal.interfaces import LINEAR, ROTARY
from hal.joints import CYLINDER


def watched_joints(rig: RigConfig) -> list[str]:
    """The joints a model runs beside: rotary cylinder joints on regulators with an identified
    model, and linear axes (a cylinder on a 5/3 valve) with a transmitter on each chamber (their
    model starts from the chambers' measured pressures: :mod:`controllers.drift_axis`). The
    muscle joint has no model here yet."""
    return [j.name for j in rig.joints
            if (j.kind == ROTARY and j.actuation == CYLINDER and j.head is not None and rig.joint_params(j) is not None)
            or (j.kind == LINEAR and j.linear_axis is not None and j.pressure_head is not None
                and j.pressure_rod is not None)]


class ModelWatch:
    """Every watched joint of a rig, fed the ``state`` message's columns (layout field names:
    docs/protocol.md "The cycle record")."""

    def __init__(self, rig: RigConfig, dt: float = 0.001):
        self.config = rig.model_watch
        kinds = {j.name: j.kind for j in rig.joints}
        self.joints = {name: (AxisWatch if kinds[name] == LINEAR else JointWatch)(name, rig, self.config, dt)
                       for name in watched_joints(rig)}
        self._last_cycle: int | None = None
        self.t = math.nan

    def feed(self, columns: dict) -> dict[str, list[float]]:
        """One ``state`` message: the residual per joint per row, in the joint's unit (NaN where
        none). A gap in the cycles (messages lost) starts every model again."""
        cycles = columns["cycle"]
        if cycles and self._last_cycle is not None and cycles[0] != self._last_cycle + 1:
            for w in self.joints.values():
                w.restart()
        if cycles:
            self._last_cycle = cycles[-1]
            self.t = columns["t"][-1]
        return {name: w.feed_columns(columns) for name, w in self.joints.items()}

    def judge(self) -> tuple[dict, list[Verdict]]:
        """The ``model`` topic's message (each joint's statistics) and the verdicts that changed."""
        message, verdicts = {"t": self.t, "band_deg": self.config.band_deg, "window_s": self.config.window_s,
                             "joints": {}}, []
        for name, w in self.joints.items():
            stats = {**w.statistics(), f"band_{w.unit}": w.band, "band_from": w.band_from, "unit": w.unit}
            message["joints"][name] = stats
            rms = stats[f"rms_{w.unit}"]
            verdict = w.judge(self.t, stats) if stats["anchored"] and math.isfinite(rms) else None
            stats["flagged"] = w.flagged  # as judged now: the message of a drift's event says so
            if verdict is not None:
                verdicts.append(verdict)
        return message, verdicts
