"""The array pressure sensor (rig-facts §3): a 16 x 16 taxel pad, 40 x 40 mm, 0-1025 kPa,
read through a multiplexed 16-bit A/D as one frame of volts per scan.

A frame of volts becomes a frame of pressures [Pa] by each taxel's own linear calibration,
``p = gain_pa_per_v[i] * (V - offset_v[i])``; dead taxels (a broken trace reads a constant)
are masked as NaN, so an estimator knows the value is missing rather than zero. A frame is
implausible when a live taxel reads more than ``margin`` of full scale outside 0..full scale
(a saturated or disconnected multiplexer), or when it has the wrong size: :meth:`pressures`
raises :class:`ValueError` saying which, so a stream of such frames cannot pass as contact.

Frames come from a **named source**, as transports are named (hal.transport): the rig file's
``contact_sensor.source`` is a name in :data:`FRAME_SOURCES` or a ``module:Class`` path of a
:class:`FrameSource`, loaded by name in the sensor's process (the simulated pad is one such
source, sim_backend.contact_patch's); an unknown one is refused when the rig file is read.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from hal.plugins import load_class
from hal.schema import require

TAXELS = 16  # per side
PAD_M = 0.040  # side of the pad [m]
FULL_SCALE_PA = 1.025e6
ACCURACY_PA = 0.005 * FULL_SCALE_PA  # +-0.5 % FS (rig-facts §3)
SENSING_SIDE_M = 1.9e-6 ** 0.5  # each taxel senses about 1.9 mm^2: a square of 1.38 mm


def sensing_offsets_m(n: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """dx, dy [m] of n x n points spread over a taxel's sensing square, whose mean pressure
    the taxel reports: how the simulator reads a contact and the estimator models it."""
    offsets = (np.arange(n) - (n - 1) / 2) * SENSING_SIDE_M / n
    dx, dy = np.meshgrid(offsets, offsets)
    return dx.ravel(), dy.ravel()


@dataclass(frozen=True)
class TaxelCalibration:
    """Per-taxel calibration, row-major (row = y, column = x); ``dead``: (row, column) pairs."""

    offset_v: np.ndarray = field(default_factory=lambda: np.zeros((TAXELS, TAXELS)))
    gain_pa_per_v: np.ndarray = field(default_factory=lambda: np.full((TAXELS, TAXELS), FULL_SCALE_PA / 10.0))
    dead: tuple[tuple[int, int], ...] = ()
    margin: float = 0.05  # of full scale, outside 0..FS before a frame is implausible

    def __post_init__(self):
        for name in ("offset_v", "gain_pa_per_v"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (TAXELS, TAXELS) or not np.all(np.isfinite(value)):
                raise ValueError(f"taxel calibration: {name} must be {TAXELS} x {TAXELS} finite numbers")
            object.__setattr__(self, name, value)
        if np.any(self.gain_pa_per_v == 0):
            raise ValueError("taxel calibration: gain_pa_per_v must not be zero")
        for row, col in self.dead:
            if not (0 <= row < TAXELS and 0 <= col < TAXELS):
                raise ValueError(f"taxel calibration: dead taxel ({row}, {col}) is outside the {TAXELS} x {TAXELS} pad")


@dataclass(frozen=True)
class ContactSensorConfig:
    """The rig file's ``[contact_sensor]``: the array sensor read and its contact estimated in
    a process beside the loop (daemon.contact.process). ``offset_v`` and ``gain_pa_per_v``:
    one number for every taxel, or 256 row by row; ``dead``: [row, column] pairs;
    ``memory_ms`` and ``beta_memory_ms``: the estimator's memories (controllers.contact_force).
    ``source`` names where frames come from (:data:`FRAME_SOURCES` or ``module:Class``): ``"sim"``
    is the simulated pad, pressed by an impact at ``sim_impact_speed_m_s`` every
    ``sim_impact_every_s`` (sim_backend.contact_patch). ``open_timeout_s``: how long the daemon's
    start waits for the sensor process's first estimate (a busy machine starts it slowly)."""

    source: str = "sim"
    rate_hz: float = 4000.0
    offset_v: tuple[float, ...] = (0.0,)
    gain_pa_per_v: tuple[float, ...] = (FULL_SCALE_PA / 10.0,)
    dead: tuple[tuple[int, ...], ...] = ()
    memory_ms: float = 4.0
    beta_memory_ms: float = 8.0
    sim_impact_speed_m_s: float = 0.08
    sim_impact_every_s: float = 1.0
    seed: int = 0
    open_timeout_s: float = 10.0

    def __post_init__(self):
        try:
            load_frame_source(self.source)
        except LookupError as exc:
            require(False, "source", str(exc))
        require(100.0 <= self.rate_hz <= 10000.0, "rate_hz", f"must be within 100-10000 Hz, got {self.rate_hz}")
        for name in ("offset_v", "gain_pa_per_v"):
            require(len(getattr(self, name)) in (1, TAXELS * TAXELS), name,
                    f"one number, or {TAXELS * TAXELS} (row by row); got {len(getattr(self, name))}")
        require(all(g != 0 for g in self.gain_pa_per_v), "gain_pa_per_v", "must not be zero")
        for i, pair in enumerate(self.dead):
            require(len(pair) == 2 and all(0 <= v < TAXELS for v in pair), f"dead[{i}]",
                    f"a [row, column] pair within 0-{TAXELS - 1}, got {list(pair)}")
        for name in ("memory_ms", "beta_memory_ms"):
            require(0.0 < getattr(self, name) <= 1000.0, name, f"must be within (0, 1000] ms, got {getattr(self, name)}")
        require(0.0 < self.sim_impact_speed_m_s <= 0.2, "sim_impact_speed_m_s",
                f"must be within (0, 0.2] m/s, got {self.sim_impact_speed_m_s}")
        require(0.5 <= self.sim_impact_every_s <= 10.0, "sim_impact_every_s",
                f"must be within 0.5-10 s (an impact lasts 0.5 s), got {self.sim_impact_every_s}")
        require(0.0 < self.open_timeout_s <= 600.0, "open_timeout_s",
                f"must be within (0, 600] s, got {self.open_timeout_s}")

    def calibration(self) -> "TaxelCalibration":
        def per_taxel(values):
            return np.broadcast_to(np.asarray(values, float), (TAXELS * TAXELS,)).reshape(TAXELS, TAXELS)
        return TaxelCalibration(per_taxel(self.offset_v), per_taxel(self.gain_pa_per_v),
                                tuple((int(r), int(c)) for r, c in self.dead))


class FrameSource(ABC):
    """Where a contact sensor's frames come from, built in the sensor's process from the rig
    file's ``[contact_sensor]``: a real A/D's driver, or a simulator."""

    @classmethod
    @abstractmethod
    def from_config(cls, config: ContactSensorConfig) -> "FrameSource":
        ...

    @abstractmethod
    def frame(self, k: int) -> np.ndarray:
        """Frame k's volts, one per taxel (k counts from the first frame, at ``rate_hz``)."""


FRAME_SOURCES: dict[str, str] = {
    "sim": "sim_backend.contact_patch:ImpactReplay",
}


def load_frame_source(name: str) -> type[FrameSource]:
    """The frame source class for a name or a ``module:Class`` path (LookupError if none)."""
    return load_class(name, FRAME_SOURCES, FrameSource, "contact sensor source")


def taxel_centres_m() -> tuple[np.ndarray, np.ndarray]:
    """x, y [m] of every taxel's centre, pad centre at 0 (arrays of shape (16, 16))."""
    pitch = PAD_M / TAXELS
    axis = (np.arange(TAXELS) + 0.5) * pitch - PAD_M / 2
    return np.meshgrid(axis, axis)


class TaxelArray:
    """Volts per taxel -> pressure [Pa] per taxel, dead taxels NaN."""

    def __init__(self, calibration: TaxelCalibration = TaxelCalibration()):
        self.calibration = calibration
        self.live = np.ones((TAXELS, TAXELS), dtype=bool)
        for row, col in calibration.dead:
            self.live[row, col] = False

    def pressures(self, volts) -> np.ndarray:
        """One frame [Pa]; ValueError on a frame that cannot be a reading (see the module)."""
        v = np.asarray(volts, dtype=float)
        if v.size != TAXELS * TAXELS:
            raise ValueError(f"taxel frame: {v.size} values, want {TAXELS * TAXELS}")
        c = self.calibration
        p = c.gain_pa_per_v * (v.reshape(TAXELS, TAXELS) - c.offset_v)
        live = p[self.live]
        bound = c.margin * FULL_SCALE_PA
        if not np.all(np.isfinite(live)) or np.any(live < -bound) or np.any(live > FULL_SCALE_PA + bound):
            worst = live[~np.isfinite(live)] if not np.all(np.isfinite(live)) else live[np.argmax(np.abs(live - FULL_SCALE_PA / 2))]
            raise ValueError(f"taxel frame: a live taxel reads {float(np.ravel(worst)[0]) / 1e3:.1f} kPa, "
                             f"outside 0..{FULL_SCALE_PA / 1e3:.0f} kPa by more than {c.margin:.0%} of full scale")
        return np.where(self.live, p, np.nan)

    def volts_for(self, pressures_pa: np.ndarray) -> np.ndarray:
        """The volts this calibration expects for a frame of pressures (for simulators)."""
        c = self.calibration
        return np.asarray(pressures_pa, dtype=float) / c.gain_pa_per_v + c.offset_v


@dataclass(frozen=True)
class Contact:
    """A contact on the pad (rig-facts §3): centre, semi-axes along x and y [m], peak pressure
    [Pa], shape beta; p = p_max (1 - (x - cx)^2/a^2 - (y - cy)^2/b^2)^beta inside, 0 outside.
    What the simulator presses into the pad and what the estimator identifies."""

    cx: float
    cy: float
    a: float
    b: float
    p_max: float
    beta: float

    def pressure(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        phi = 1.0 - ((x - self.cx) / self.a) ** 2 - ((y - self.cy) / self.b) ** 2
        return np.where(phi > 0, self.p_max * np.clip(phi, 0.0, None) ** self.beta, 0.0)

    @property
    def force_n(self) -> float:
        """Total normal force [N]: the integral of p over the ellipse, pi a b p_max / (beta + 1)."""
        return math.pi * self.a * self.b * self.p_max / (self.beta + 1.0)

    @property
    def area_m2(self) -> float:
        return math.pi * self.a * self.b
