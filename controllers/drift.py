"""The rig's model beside the arm: each cylinder joint's identified model (rig-facts §1
[2-36..2-45], :class:`hal.joint_model.JointModel`, the simulator's own plant) driven by the
chamber pressures the loop commanded, cycle by cycle, and its position compared with the one
the loop read. The residual r = measured - predicted [deg] and its statistics over a window
are what the ``model`` topic carries; its RMS beyond the rig file's band (``[model_watch]``)
for a while is drift, and the shape of the residual since it left zero names the likely cause.

**Anchoring.** The model's chambers follow the commanded pressures from the first cycle it is
fed (and again after a gap in the cycles); after the dead time and five regulator lags
(T_dly + 5 T_ep) their start no longer shows (e^-5), and the model starts from the measured
angle, moving at its slope over those last moments (not at the loop's velocity estimate: its
noise is larger than the Stribeck velocity, :meth:`JointWatch._anchor`). From then on it runs
free on the commands: it is never corrected by the measurement, so a drift is not absorbed (an
observer would learn a potentiometer's offset as the state). The joint model is stable (spring
K, damping D), so a model error does not grow without bound.

**Naming the cause** (:func:`name_cause`). A small drift of parameter q changes the
prediction by q times its sensitivity s_q(t) = d(predicted)/dq along the run: a
potentiometer's offset, s = 1 deg/deg (a step); a leak in the head (rod) chamber, the response
to a fraction of that chamber's pressure lost; a regulator's gain, to a fraction of both
lost; friction, to [2-45]'s Fs and Fc grown by a fraction. Each is simulated from the residual's
onset on the commands kept (``history_s``), by the same model from its state at the onset,
and fitted to the residual by least squares (one number each: the fault's size); the one
that explains most of the residual (R^2 at least ``EXPLAINED``, ``MARGIN`` more than the
runner-up's, its size plausible) is named, else the cause is "unclear" and the two best are
said. Over the first seconds of a drift the candidates' shapes are alike (a slow departure):
on the simulator a regulator gain of 0.8 was named grown friction at its flag (R^2 0.99) and a
gain change 10 s on (docs/model.md), so the naming is a hint, the flag is the finding.
"""
from __future__ import annotations

import copy
import itertools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from hal.config import JointConfig, RigConfig
from hal.identified import identification
from hal.rig_sections import ModelWatchConfig
from hal.joint_model import JointModel
from hal.interfaces import LINEAR

EPS = 0.05  # the fraction each candidate's sensitivity is simulated at [-]
EXPLAINED = 0.8  # R^2 a candidate must reach to be named [-]
MARGIN = 0.01  # ... and by how much it must beat the runner-up [-]
MAX_STEPS = 10_000  # a gap between two cycles longer than this many model steps (10 s) starts the model again
SNAPSHOT_S = 0.5  # the model's state is kept this often, to replay a candidate from the onset [s]
NAME_AGAIN_S = 10.0  # the cause is named again this long after the drift's event, on more of it [s]
ONSET_FRACTION = 0.25  # the residual's onset: where |r| last was below this fraction of the band
# the band from an identification: this many times the residual RMS it found on held-out data
# (a window's RMS on the simulator's nominal hour came to at most 1.8 times its mean, docs/model.md)
BAND_PER_RMS = 3.0
CAUSES = {  # candidate -> (what the event says, the size's name, its plausible range)
    "offset": ("a potentiometer offset", "offset_deg", (-90.0, 90.0)),
    "leak_head": ("a leak in the head chamber", "leak_fraction", (0.0, 1.0)),
    "leak_rod": ("a leak in the rod chamber", "leak_fraction", (0.0, 1.0)),
    "gain": ("a regulator gain change", "gain_loss", (-1.0, 1.0)),
    "friction": ("friction changed", "friction_growth", (-0.9, 20.0)),
}


@dataclass
class Verdict:
    """What a joint's watch says after a batch: an event's content when the verdict changed."""

    joint: str
    action: str  # "drift" (left the band), "cause" (named again on more of the drift) or "recovered" (back inside)
    cause: str
    details: dict


def band_of(rig: RigConfig, joint: JointConfig) -> tuple[float, str]:
    """The band a joint's residual RMS is judged against (in its unit: deg rotary, mm linear), and
    where it came from: BAND_PER_RMS times the held-out residual RMS the identification that wrote
    the joint's model found (its table's ``heldout_rms_deg``), else the rig file's
    ``[model_watch] band_deg`` (a linear axis: ``band_mm``)."""
    if joint.kind == LINEAR:
        return rig.model_watch.band_mm, "rig file: [model_watch] band_mm"
    rms = identification(rig.models.get(joint.model_name) or {}).get("heldout_rms_deg")
    if rms is not None:
        return BAND_PER_RMS * rms, (f"identification: {BAND_PER_RMS:g} x the held-out residual RMS {rms:.3g} deg "
                                    f"of models.{joint.model_name}")
    return rig.model_watch.band_deg, "rig file: [model_watch] band_deg"


class JointWatch:
    """One cylinder joint's model beside the arm, its residual history and its verdict."""

    unit = "deg"  # the residual's, its statistics' and the band's
    causes = CAUSES  # the candidates it names

    def __init__(self, name: str, rig: RigConfig, config: ModelWatchConfig, dt: float = 0.001):
        jc = next(j for j in rig.joints if j.name == name)
        self.name, self.config, self.dt = name, config, dt
        # a gap between two cycles the loop would trip at (it stalled: the arm went on unseen, a
        # simulated plant may have skipped steps) starts the model again from the arm
        self.max_steps = min(MAX_STEPS, max(1, int(rig.safety.stall_after_s / dt)))
        self.params = rig.joint_params(jc)
        self.band, self.band_from = band_of(rig, jc)
        self.neutral_deg = jc.neutral_deg
        margin = 10.0  # the simulator's end stops beyond the software limits (sim_backend.options) [deg]
        self.stops = (jc.min_angle_deg - margin, jc.max_angle_deg + margin)
        self.settle_s = self.params.T_dly + 5.0 * self.params.T_ep  # the chambers' warm-up: their start gone [s]
        self.model: JointModel | None = None  # anchored: predicting
        self._warming: JointModel | None = None  # its chambers following the commands, not yet anchored
        self._warm_since = 0.0
        self._warm_samples: list[tuple[float, float]] = []  # (t, measured angle) over the warm-up
        n = int(round(config.history_s / dt))
        # per sample: its time, the command held since the sample before (and for how many
        # model steps), what was measured and what the model predicted
        self.history = {k: deque(maxlen=n) for k in ("t", "head", "rod", "steps", "measured", "predicted")}
        self._pending: tuple[float, float, float] | None = None  # (t, head, rod) of the last cycle: in force now
        self._t0, self._grid = 0.0, 0  # [s] the first cycle's time, and the model's steps since it
        self._snapshots: deque[tuple[int, JointModel]] = deque(maxlen=int(config.history_s / SNAPSHOT_S) + 2)
        self._count = 0  # samples fed since the model was anchored (indexes the snapshots)
        self._next_snapshot = 0
        self.residual: deque[float] = deque(maxlen=n)  # measured - predicted per sample [deg]
        self._anchored_t = math.nan  # [s] when the model started
        self.outside_since: float | None = None
        self.inside_since: float | None = None
        self.flagged = False
        self.cause: dict | None = None  # the last drift's named cause
        self._name_again_at: float | None = None  # [s] when the cause is named again, on more of the drift

    # -- feeding -----------------------------------------------------------------------------
    def feed(self, t: float, head_pa: float, rod_pa: float, measured_rad: float) -> float:
        """One cycle at ``t`` [s]: the position [rad] the loop read, and the
        pressures [Pa] it then commanded, held until its next cycle. The model first steps on the
        previous cycle's command for the time between the two (the plant steps by its clock: a
        late cycle held the command for several steps). The residual [deg] (NaN before the
        model is anchored)."""
        if not (math.isfinite(head_pa) and math.isfinite(rod_pa) and math.isfinite(measured_rad)):
            self.restart()  # (a cycle without a reading or a command: the model has lost the arm)
            return math.nan
        measured = math.degrees(measured_rad)
        previous, self._pending = self._pending, (t, head_pa, rod_pa)
        # the plant's steps between the two cycles, on its grid of dt from the first (two cycles
        # closer than a step, a late one's catching up, may share one: no step between them)
        grid = int(math.floor((t - self._t0) / self.dt + 0.5)) if previous is not None else 0
        steps, self._grid = grid - self._grid, grid
        if previous is None:
            self._t0 = t
        elif not 0 <= steps <= self.max_steps:
            self.restart()  # the clock went back, or a gap too long to step over
            self._pending, self._t0 = (t, head_pa, rod_pa), t
            return math.nan
        model = self.model
        if model is None:
            self._anchor(t, previous, steps, measured)
            return math.nan
        for _ in range(steps):
            model.step(previous[1], previous[2])
        predicted = model.th
        h = self.history
        for key, value in (("t", t), ("head", previous[1]), ("rod", previous[2]), ("steps", steps),
                           ("measured", measured), ("predicted", predicted)):
            h[key].append(value)
        self.residual.append(measured - predicted)
        self._count += 1
        if self._count >= self._next_snapshot:
            self._snapshots.append((self._count, copy.deepcopy(model)))
            self._next_snapshot = self._count + int(round(SNAPSHOT_S / self.dt))
        return measured - predicted

    def _anchor(self, t: float, previous: tuple | None, steps: int, measured: float) -> None:
        """Warm the model's chambers on the commands for ``settle_s`` (the pressure path is the
        commands' alone: by then its start no longer shows), then start it at the measured angle,
        moving at the measured angle's slope over the warm-up. Not at the loop's velocity: its
        noise (1-6 deg/s at rest on the simulator) is larger than the Stribeck velocity vs, and
        [2-45]'s falling branch makes a joint under a torque between Fc and the map's peak creep
        or slide by where it starts: a model started sliding beside an arm that creeps leaves it
        by degrees a second."""
        if previous is None:
            return
        warm = self._warming
        if warm is None:
            warm = self._warming = JointModel(self.params, self.dt, self.neutral_deg, self.stops,
                                              initial_deg=measured, initial_pset=previous[1:])
            self._warm_since, self._warm_samples = previous[0], []
        for _ in range(steps):
            warm.step(previous[1], previous[2])
        self._warm_samples.append((t, measured))
        if t - self._warm_since >= self.settle_s and len(self._warm_samples) >= 3:
            ts, angles = np.array(self._warm_samples).T
            slope = float(np.polyfit(ts - ts[-1], angles, 1)[0])
            warm.th, warm.w = min(max(measured, self.stops[0]), self.stops[1]), slope
            self.model, self._warming, self._anchored_t = warm, None, t
            self._count = 0
            self._snapshots.append((0, copy.deepcopy(warm)))
            self._next_snapshot = int(round(SNAPSHOT_S / self.dt))

    def restart(self) -> None:
        """Forget the model's state: it anchors again once the commands hold still."""
        self.model = self._warming = self._pending = None
        self._grid = 0
        for q in (*self.history.values(), self.residual):
            q.clear()
        self._snapshots.clear()
        self._count = self._next_snapshot = 0
        self.outside_since = self.inside_since = None

    # -- judging -----------------------------------------------------------------------------
    def t_since_onset(self) -> float:
        """[s] from the named drift's onset to the last sample."""
        onset = (self.cause or {}).get("onset_t", math.nan)
        return self.history["t"][-1] - onset if self.history["t"] else math.nan

    def residuals(self) -> np.ndarray:
        return np.asarray(self.residual)

    def statistics(self) -> dict:
        """The residual over the last ``window_s`` [deg]: mean, RMS, largest |r|, and how much of
        the window the model has run for (its statistics are judged once it is full)."""
        h = self.history
        u = self.unit
        if not h["t"]:
            return {"anchored": self.model is not None, f"mean_{u}": math.nan, f"rms_{u}": math.nan,
                    f"max_abs_{u}": math.nan, "window_fill": 0.0, "flagged": self.flagged}
        now, since = h["t"][-1], h["t"][-1] - self.config.window_s
        recent = list(itertools.takewhile(lambda x: x[0] > since, zip(reversed(h["t"]), reversed(self.residual))))
        r = np.fromiter((x[1] for x in recent), float, len(recent))
        fill = min((now - self._anchored_t) / self.config.window_s, 1.0)
        return {"anchored": True, f"mean_{u}": float(r.mean()), f"rms_{u}": float(np.sqrt(np.mean(r * r))),
                f"max_abs_{u}": float(np.abs(r).max()), "window_fill": fill, "flagged": self.flagged}

    def judge(self, t: float, stats: dict) -> Verdict | None:
        """The band's verdict at ``t`` [s] on the window's ``stats``: a Verdict when the joint
        has been outside the band for ``hold_s`` (drift, its cause named) or back inside for
        ``recover_s`` after a drift (a drift that shows only while the arm moves, grown friction,
        comes back inside while it rests)."""
        band, hold, rms = self.band, self.config.hold_s, stats[f"rms_{self.unit}"]
        if stats["window_fill"] < 1.0 and not rms > band:
            return None  # a window not yet full judges only against the band's upper side
        outside = rms > band
        if outside:
            self.inside_since = None
            self.outside_since = self.outside_since if self.outside_since is not None else t
            if not self.flagged and t - self.outside_since >= hold:
                self.flagged, self._name_again_at = True, t + NAME_AGAIN_S
                self.cause = self.name_cause()
                return Verdict(self.name, "drift", _cause_text(self, stats), self.cause)
        if self.flagged and self._name_again_at is not None and t >= self._name_again_at:
            self._name_again_at = None  # the candidates' shapes part as the drift goes on: named again, once
            self.cause = self.name_cause()
            return Verdict(self.name, "cause", _cause_text(self, stats, again=True), self.cause)
        if not outside:
            self.outside_since = None
            self.inside_since = self.inside_since if self.inside_since is not None else t
            if self.flagged and t - self.inside_since >= self.config.recover_s:
                self.flagged = False
                return Verdict(self.name, "recovered",
                               f"the residual's RMS {rms:.2f} {self.unit} is back inside the band "
                               f"{band:.3g} {self.unit}", {})
        return None

    def name_cause(self) -> dict:
        return name_cause(self)

    def feed_columns(self, columns: dict) -> list[float]:
        """A ``state`` message's rows: the commanded chamber pressures and the position."""
        n = self.name
        return [self.feed(t, h, r, p) for t, h, r, p in zip(
            columns["t"], columns[f"{n}.p_head_cmd"], columns[f"{n}.p_rod_cmd"], columns[f"{n}.position"])]


def _cause_text(watch: JointWatch, stats: dict, again: bool = False) -> str:
    found, causes, u = watch.cause or {}, watch.causes, watch.unit
    what = (f"likely {causes[found['likely']][0]} ({causes[found['likely']][1]} {found['size']:.3g}, "
            f"explains {100 * found['explained']:.0f} % of the residual since its onset)"
            if found.get("likely") else
            f"cause unclear (best: {causes[found['best']][0]}, explains {100 * found['explained']:.0f} %; then "
            f"{causes[found['runner_up']][0] if found.get('runner_up') else 'none'})"
            if found.get("best") else "cause unclear")
    if again:
        return f"named again on {watch.t_since_onset():.0f} s of the drift: {what}"
    return (f"the arm left its model: residual RMS {stats[f'rms_{u}']:.2f} {u} (mean {stats[f'mean_{u}']:+.2f} {u}) "
            f"over {watch.config.window_s:g} s, band {watch.band:.3g} {u}; {what}")


def name_cause(watch: JointWatch) -> dict:
    """Each candidate's effect on the prediction, simulated from the residual's onset on the
    commands kept, fitted to the residual: the likely one (or None), the best one, how much
    of the residual it explains (R^2), its size, and the onset's time [s]."""
    r = watch.residuals()
    h = watch.history
    if len(r) < 10 or not watch._snapshots:
        return {"likely": None, "best": None, "explained": 0.0, "size": math.nan, "onset_t": math.nan}
    quiet = np.flatnonzero(np.abs(r) <= ONSET_FRACTION * watch.band)
    onset = int(quiet[-1]) + 1 if len(quiet) else 0
    onset = max(min(onset, len(r) - 5), 0)
    first = watch._count - len(r)  # samples are counted from 1 at the anchor: history[i] is sample first + i + 1
    kept = [s for s in watch._snapshots if s[0] >= first]  # the model's states whose commands are still kept
    if not kept:
        return {"likely": None, "best": None, "explained": 0.0, "size": math.nan, "onset_t": math.nan}
    base = max((s for s in kept if s[0] <= first + onset + 1), key=lambda s: s[0], default=kept[0])
    head, rod, steps = np.asarray(h["head"]), np.asarray(h["rod"]), np.asarray(h["steps"], dtype=int)

    def advance(model: JointModel, i: int, scale_head: float = 1.0, scale_rod: float = 1.0) -> None:
        for _ in range(steps[i]):  # sample i's command, for the steps it was held
            model.step(head[i] * scale_head, rod[i] * scale_rod)

    nominal = copy.deepcopy(base[1])  # the state at sample base[0]
    i = base[0] - first  # the next sample's index
    onset = max(onset, i - 1)
    while i <= onset:
        advance(nominal, i)
        i += 1
    members = {name: copy.deepcopy(nominal) for name in ("nominal", "leak_head", "leak_rod", "gain", "friction")}
    members["friction"].scale_friction(1.0 + EPS)
    scales = {"nominal": (1.0, 1.0), "leak_head": (1 - EPS, 1.0), "leak_rod": (1.0, 1 - EPS),
              "gain": (1 - EPS, 1 - EPS), "friction": (1.0, 1.0)}
    track = {name: np.empty(len(r) - onset) for name in members}
    for name, m in members.items():
        track[name][0] = m.th
    for i in range(onset + 1, len(r)):
        for name, m in members.items():
            advance(m, i, *scales[name])
            track[name][i - onset] = m.th
    y = r[onset:]
    sensitivities = {"offset": np.ones_like(y)}
    for name in ("leak_head", "leak_rod", "gain", "friction"):
        # an arm with the fault at size q reads about the nominal prediction plus q times this
        sensitivities[name] = (track[name] - track["nominal"]) / EPS
    energy = float(y @ y)
    fits = {}
    for name, s in sensitivities.items():
        ss = float(s @ s)
        if ss <= 0.0 or energy <= 0.0:
            continue
        size = float(s @ y) / ss
        fits[name] = (1.0 - float(((y - size * s) @ (y - size * s))) / energy, size)
    if not fits:
        return {"likely": None, "best": None, "explained": 0.0, "size": math.nan, "onset_t": float(h["t"][onset])}
    # a size outside its candidate's range is no explanation (a leak that gained pressure)
    ranked = sorted((n for n in fits if CAUSES[n][2][0] < fits[n][1] < CAUSES[n][2][1]), key=lambda n: fits[n][0],
                    reverse=True) or sorted(fits, key=lambda n: fits[n][0], reverse=True)
    best = ranked[0]
    explained, size = fits[best]
    low, high = CAUSES[best][2]
    runner_up = fits[ranked[1]][0] if len(ranked) > 1 else -math.inf
    likely = best if explained >= EXPLAINED and low < size < high and explained - runner_up >= MARGIN else None
    return {"likely": likely, "best": best, "runner_up": ranked[1] if len(ranked) > 1 else None,
            "explained": explained, "size": size, "onset_t": float(h["t"][onset]),
            "fits": {n: {"explained": f[0], "size": f[1]} for n, f in fits.items()}}
