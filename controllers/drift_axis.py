"""The model beside a linear pneumatic axis (rig-facts §5; docs/model.md): the axis's model
(:class:`hal.axis_model.AxisModel`, the simulator's own plant, on the joint's
``[joints.linear_axis]``) driven by the volts the loop wrote to its valve (the cycle record's
``out.<channel>``), cycle by cycle, its position compared with the one the loop read. The
residual r = measured - predicted [mm]; the statistics, the band (``[model_watch] band_mm``),
the verdicts and the restarts are the rotary watch's (:class:`controllers.drift.JointWatch`).

**Anchoring.** A valve commands flow, not pressure: the chambers' pressures are the integral of
the flows since ever, so no warm-up on the commands alone finds them. The axis's transmitters
measure them; the model starts from them, from the measured position, and from the position's
slope over a warm-up of ``WARM_S`` (the line fitted to it: its end is the position; the spool
follows its command through it: five of its lags). From then on it runs free on the valve
command, never corrected by the measurement. The axis integrates flow: a start slightly off
(its velocity, or where a breakaway from stiction falls) leaves an offset that stays, where the
rotary joint's spring lets it die out; a restart at the start of a move is the worst case
(docs/model.md gives the figures).

**Naming the cause.** Only one candidate here: a position-sensor offset (the residual a step
since its onset, 1 mm/mm). A leak, grown friction or a lost supply have no sensitivity computed
for the axis yet; a residual the offset does not explain is "unclear".
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from controllers.drift import EXPLAINED, MAX_STEPS, ONSET_FRACTION, JointWatch, band_of
from hal.config import RigConfig
from hal.linear_axis import AxisState
from hal.linear_axis_facts import rest_state
from hal.rig_sections import ModelWatchConfig
from hal.axis_model import AxisModel

# [s] the warm-up: the spool's lag (2 ms) gone, and the position's slope over it. Short: a line over
# an accelerating start lags its velocity, and the axis integrates a velocity error into an offset
# that stays (restarted at 16 points of a swing: 0.9 mm at worst over 50 ms, 0.4 mm over 20 ms,
# 0.11 mm over 10 ms, where the slope's noise is about 2.5 mm/s)
WARM_S = 0.01
AXIS_CAUSES = {"offset": ("a position-sensor offset", "offset_mm", (-100.0, 100.0))}


class AxisWatch(JointWatch):
    """One linear axis's model beside it, its residual [mm] and its verdict."""

    unit = "mm"
    causes = AXIS_CAUSES

    def __init__(self, name: str, rig: RigConfig, config: ModelWatchConfig, dt: float = 0.001):
        jc = next(j for j in rig.joints if j.name == name)
        self.name, self.config, self.dt = name, config, dt
        self.max_steps = min(MAX_STEPS, max(1, int(rig.safety.stall_after_s / dt)))
        self.params = jc.linear_axis
        self.valve_field = f"out.{jc.valve.channel}"  # the volts the valve was given (the loop's output, its clamps applied)
        self.band, self.band_from = band_of(rig, jc)
        self.settle_s = max(WARM_S, 5.0 * self.params.valve_time_constant_s)
        self.model: AxisModel | None = None
        self._warming: AxisModel | None = None
        self._warm_since = 0.0
        self._warm_samples: list[tuple[float, float]] = []  # (t [s], measured position [m])
        n = int(round(config.history_s / dt))
        self.history = {k: deque(maxlen=n) for k in ("t", "volts", "steps", "measured", "predicted")}
        self._pending: tuple[float, float] | None = None  # (t, volts) of the last cycle: in force now
        self._t0, self._grid = 0.0, 0
        self._snapshots: deque = deque()  # (none kept: the one candidate needs no replay)
        self._count = self._next_snapshot = 0
        self.residual: deque[float] = deque(maxlen=n)  # measured - predicted per sample [mm]
        self._anchored_t = math.nan
        self.outside_since: float | None = None
        self.inside_since: float | None = None
        self.flagged = False
        self.cause: dict | None = None
        self._name_again_at: float | None = None

    def feed_columns(self, columns: dict) -> list[float]:
        """A ``state`` message's rows: the valve's output, the position, the chambers' pressures."""
        n = self.name
        return [self.feed(*row) for row in zip(columns["t"], columns[self.valve_field], columns[f"{n}.position"],
                                               columns[f"{n}.p_head"], columns[f"{n}.p_rod"])]

    def feed(self, t: float, volts: float, measured_m: float, head_pa: float, rod_pa: float) -> float:
        """One cycle at ``t`` [s]: the position [m] and chamber pressures [Pa gauge] the loop read,
        and the valve command [V] it then wrote, held until its next cycle. The residual [mm]
        (NaN before the model is anchored)."""
        if not all(math.isfinite(x) for x in (volts, measured_m, head_pa, rod_pa)):
            self.restart()
            return math.nan
        previous, self._pending = self._pending, (t, volts)
        grid = int(math.floor((t - self._t0) / self.dt + 0.5)) if previous is not None else 0
        steps, self._grid = grid - self._grid, grid
        if previous is None:
            self._t0 = t
        elif not 0 <= steps <= self.max_steps:
            self.restart()
            self._pending, self._t0 = (t, volts), t
            return math.nan
        model = self.model
        if model is None:
            self._anchor(t, previous, steps, measured_m, head_pa, rod_pa)
            return math.nan
        for _ in range(steps):
            model.step(previous[1])
        measured, predicted = measured_m * 1e3, model.position_m * 1e3
        h = self.history
        for key, value in (("t", t), ("volts", previous[1]), ("steps", steps), ("measured", measured),
                           ("predicted", predicted)):
            h[key].append(value)
        self.residual.append(measured - predicted)
        self._count += 1
        return measured - predicted

    def _anchor(self, t: float, previous: tuple | None, steps: int, measured_m: float, head_pa: float,
                rod_pa: float) -> None:
        """Step a model's spool on the commands for ``settle_s``, then start it at the measured
        position, chamber pressures (gauge + the atmosphere) and the position's slope over the
        last ``WARM_S``."""
        if previous is None:
            return
        p = self.params
        warm = self._warming
        if warm is None:
            x = min(max(measured_m, 0.0), p.stroke_m)
            warm = self._warming = AxisModel(p, self.dt, rest_state(p, x))
            self._warm_since, self._warm_samples = previous[0], []
        for _ in range(steps):
            warm.step(previous[1])
        self._warm_samples.append((t, measured_m))
        if t - self._warm_since >= self.settle_s and len(self._warm_samples) >= 3:
            recent = [s for s in self._warm_samples if s[0] > t - WARM_S - 1e-9]
            ts, xs = np.array(recent if len(recent) >= 3 else self._warm_samples[-3:]).T
            # the line through the last WARM_S of positions: its slope the velocity, its end the
            # position (less noisy than the last sample alone)
            slope, at_end = (float(c) for c in np.polyfit(ts - ts[-1], xs, 1))
            x = min(max(at_end, 0.0), p.stroke_m)
            warm.reset(AxisState(x, slope, head_pa + p.atmosphere_pa, rod_pa + p.atmosphere_pa, warm.spool))
            self.model, self._warming, self._anchored_t = warm, None, t
            self._count = 0

    def name_cause(self) -> dict:
        """The residual since its onset (where |r| was last below a quarter of the band) fitted by
        a step: an offset of the position sensor [mm] if it explains EXPLAINED of it."""
        r = np.asarray(self.residual)
        if len(r) < 10:
            return {"likely": None, "best": None, "explained": 0.0, "size": math.nan, "onset_t": math.nan}
        quiet = np.flatnonzero(np.abs(r) <= ONSET_FRACTION * self.band)
        onset = max(min(int(quiet[-1]) + 1 if len(quiet) else 0, len(r) - 5), 0)
        y = r[onset:]
        energy = float(y @ y)
        size = float(y.mean())
        explained = 1.0 - float(((y - size) @ (y - size))) / energy if energy > 0.0 else 0.0
        low, high = AXIS_CAUSES["offset"][2]
        likely = "offset" if explained >= EXPLAINED and low < size < high else None
        return {"likely": likely, "best": "offset", "runner_up": None, "explained": explained, "size": size,
                "onset_t": float(self.history["t"][onset]),
                "fits": {"offset": {"explained": explained, "size": size}}}
