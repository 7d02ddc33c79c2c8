"""A contact patch pressed into the array pressure sensor's pad by an impact (rig-facts §3),
read as the sensor reads it.

Contact model (rig-facts §3): an elliptical area, semi-axes a (along x) and b (along y), with

    p(x, y) = p_max (1 - (x - cx)^2/a^2 - (y - cy)^2/b^2)^beta   inside, 0 outside   [Pa, m]

**Interpretation** (the paper's impact records are not legible): an impact at speed v lasts
``duration_s`` (0.5 s, the paper's) as a half sine of indentation, s(t) = sin(pi t / T); by
Hertz's scaling the peak contact radius and pressure grow as v^0.4 and, within the impact,
as s^0.5 (a = a_peak s^0.5, p_max = p_peak s^0.5); beta rises from 0.5 (Hertz) towards
``beta_peak`` as the body's surface conforms (beta = 0.5 + (beta_peak - 0.5) s); the centre
slides at ``slide_m_s``. At 0.11 m/s the peak is 14 x 11 mm and 600 kPa, at 0.03 m/s 8.3 x
6.7 mm and 360 kPa (b / a = 0.8): within the pad and its range.

Impacts away from that shape, for trying an estimator on what it was not tuned on: the peak
at ``loading_fraction`` of the impact (0.5: the half sine; less: a fast load and a slow
release, s(t) a quarter sine up and another down), an aspect b / a that moves from
``aspect`` to ``aspect_end`` over the impact, and a pad whose noise is ``noise_scale`` times
the sensor's accuracy.

The sensor: each taxel reports the mean pressure over its sensing area (1.9 mm^2, a square
of 1.38 mm, sampled 3 x 3), plus noise uniform within its +-0.5 % FS accuracy, clipped to
0..FS, quantised by its 16-bit A/D; through a per-taxel calibration (a spread of gains and
offsets the device's calibration undoes) and dead taxels that read 0 V.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hal.taxel_array import (
    ACCURACY_PA,
    FULL_SCALE_PA,
    TAXELS,
    Contact,
    ContactSensorConfig,
    FrameSource,
    TaxelArray,
    TaxelCalibration,
    sensing_offsets_m,
    taxel_centres_m,
)

ADC_BITS = 16
ADC_SPAN_V = 10.0


@dataclass(frozen=True)
class Impact:
    """One impact's contact over time (see the module's interpretation)."""

    speed_m_s: float = 0.08
    duration_s: float = 0.5
    centre_m: tuple[float, float] = (0.0, 0.0)
    slide_m_s: tuple[float, float] = (0.008, -0.004)
    aspect: float = 0.8  # b / a
    beta_peak: float = 0.8
    loading_fraction: float = 0.5  # of the impact, to the peak
    aspect_end: float | None = None  # b / a at the end (None: ``aspect`` throughout)

    def __post_init__(self):
        if not 0.0 < self.speed_m_s <= 0.2:
            raise ValueError(f"impact speed {self.speed_m_s} m/s: 0 < v <= 0.2")
        if not 0.05 <= self.loading_fraction <= 0.95:
            raise ValueError(f"loading fraction {self.loading_fraction}: 0.05-0.95")

    @property
    def a_peak_m(self) -> float:
        return 0.014 * (self.speed_m_s / 0.11) ** 0.4

    @property
    def p_peak_pa(self) -> float:
        return 6.0e5 * (self.speed_m_s / 0.11) ** 0.4

    def at(self, t: float) -> Contact | None:
        """The contact at time t [s] from first touch, or None when there is none."""
        if not 0.0 < t < self.duration_s:
            return None
        peak = self.loading_fraction * self.duration_s
        if t <= peak:
            s = math.sin(0.5 * math.pi * t / peak)
        else:
            s = math.cos(0.5 * math.pi * (t - peak) / (self.duration_s - peak))
        a = self.a_peak_m * math.sqrt(s)
        end = self.aspect if self.aspect_end is None else self.aspect_end
        aspect = self.aspect + (end - self.aspect) * t / self.duration_s
        return Contact(self.centre_m[0] + self.slide_m_s[0] * t, self.centre_m[1] + self.slide_m_s[1] * t,
                       a, aspect * a, self.p_peak_pa * math.sqrt(s), 0.5 + (self.beta_peak - 0.5) * s)


def spread_calibration(seed: int, dead: tuple[tuple[int, int], ...] = ((5, 9), (11, 3))) -> TaxelCalibration:
    """A pad whose taxels differ (gain +-10 %, offset +-50 mV), as a calibrated real one does."""
    rng = np.random.default_rng(seed)
    gain = FULL_SCALE_PA / 10.0 * rng.uniform(0.9, 1.1, (TAXELS, TAXELS))
    return TaxelCalibration(rng.uniform(0.0, 0.05, (TAXELS, TAXELS)), gain, dead)


class SimTaxelPad:
    """Frames of volts from a contact, as the sensor's A/D delivers them."""

    def __init__(self, calibration: TaxelCalibration, seed: int = 0, noise_scale: float = 1.0):
        self.device = TaxelArray(calibration)
        self.rng = np.random.default_rng(seed)
        self.noise_pa = noise_scale * ACCURACY_PA
        x, y = taxel_centres_m()
        dx, dy = sensing_offsets_m()
        self.x = x[..., None] + dx  # (16, 16, 9): the sensing area's sample points
        self.y = y[..., None] + dy

    def pressures(self, contact: Contact | None) -> np.ndarray:
        """The true mean pressure over each taxel's sensing area [Pa]."""
        if contact is None:
            return np.zeros((TAXELS, TAXELS))
        return contact.pressure(self.x, self.y).mean(axis=2)

    def frame_volts(self, contact: Contact | None) -> np.ndarray:
        """One frame [V]: noise, clipping to the range, calibration, quantisation, dead taxels."""
        p = self.pressures(contact) + self.rng.uniform(-self.noise_pa, self.noise_pa, (TAXELS, TAXELS))
        v = self.device.volts_for(np.clip(p, 0.0, FULL_SCALE_PA))
        lsb = ADC_SPAN_V / 2 ** ADC_BITS
        v = np.round(v / lsb) * lsb
        return np.where(self.device.live, v, 0.0)


class ImpactReplay(FrameSource):
    """The simulated sensor's frames for a sensor process (the frame source named ``"sim"``):
    an impact every ``every_s``, the pad's noise between. The frames are made once, up front
    (the impact's, and a pool of untouched ones), so the process spends its time on the
    estimator, as it would behind a real A/D; ``truth(k)`` is the contact frame k shows."""

    NOISE_FRAMES = 64

    def __init__(self, impact: Impact, every_s: float, rate_hz: float, calibration: TaxelCalibration, seed: int):
        pad = SimTaxelPad(calibration, seed)
        self.impact, self.rate_hz = impact, rate_hz
        self.cycle = max(int(round(every_s * rate_hz)), 1)
        self.touching = int(impact.duration_s * rate_hz)
        self.impact_frames = [pad.frame_volts(impact.at(self._t(k))) for k in range(self.touching)]
        self.noise_frames = [pad.frame_volts(None) for _ in range(self.NOISE_FRAMES)]

    @classmethod
    def from_config(cls, config: ContactSensorConfig) -> "ImpactReplay":
        """The rig file's ``[contact_sensor]``: its calibration, ``sim_impact_speed_m_s``,
        ``sim_impact_every_s`` and ``seed``."""
        return cls(Impact(config.sim_impact_speed_m_s), config.sim_impact_every_s, config.rate_hz,
                   config.calibration(), config.seed)

    def _t(self, k: int) -> float:
        return (k % self.cycle + 0.5) / self.rate_hz

    def frame(self, k: int) -> np.ndarray:
        """Frame k's volts (k counts from the first frame, at ``rate_hz``)."""
        i = k % self.cycle
        return self.impact_frames[i] if i < self.touching else self.noise_frames[k % self.NOISE_FRAMES]

    def truth(self, k: int) -> Contact | None:
        return self.impact.at(self._t(k)) if k % self.cycle < self.touching else None
