"""Frequency responses from experiment data, with coherence (rig-facts §1 "Experiments": the
thesis checked coherence over 0.1-1 Hz), and the joint model's own.

Open loop (input-side experiments): the H1 estimate from Welch spectra,
    G(f) = S_uy(f) / S_uu(f),   coherence = |S_uy|^2 / (S_uu S_yy).
Closed loop (reference-side experiments): under feedback the noise reaches u through the
controller, so H1 from u to y is biased towards -1/C. The joint input-output (indirect)
method estimates both responses from the reference r, which the noise does not reach, and
divides them:
    G(f) = S_ry(f) / S_ru(f),   coherence judged on r -> y.
Data are decimated to ``rate_hz`` before the spectra (the band of interest is far below the
loop's 1 kHz). Only the frequencies the input excites are kept (its power above EXCITED of
its peak: a multisine's lines, a chirp's band). G in deg/V.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import coherence, csd, decimate, welch

from controllers.identification.fit import Experiment
from controllers.signals import PRBS, Excitation, Multisine
from hal.identified import K_EP, JointParams

EXCITED = 1e-3  # a frequency is excited when the input's power there is above this of its peak


@dataclass
class Response:
    f: np.ndarray  # [Hz]
    g: np.ndarray  # complex [deg/V]
    coherence: np.ndarray  # [0..1]
    method: str  # "H1" or "joint input-output"

    def band(self, f_lo: float, f_hi: float) -> "Response":
        keep = (self.f >= f_lo) & (self.f <= f_hi)
        return Response(self.f[keep], self.g[keep], self.coherence[keep], self.method)


def _down(x: np.ndarray, factor: int) -> np.ndarray:
    x = x - np.mean(x)
    while factor > 1:  # scipy advises stages of at most 13
        step = min(factor, 10)
        while factor % step:
            step -= 1
        x = decimate(x, step, ftype="fir", zero_phase=True)
        factor //= step
    return x


def estimate(data: Experiment, rate_hz: float = 50.0, segment_s: float | None = None,
             period_s: float | None = None, transient_s: float = 0.0) -> Response:
    """G from u to y (open loop), or from r through u and y (closed loop, when ``data.r``
    moves). A periodic signal of ``period_s`` with two periods or more: the whole periods
    covering ``transient_s`` (one at least) are dropped, the rest averaged a period at a time
    with no window, so there is no leakage at its lines once the transient has gone (the
    joints' spring mode, D / K, is 11-18 s: a short experiment keeps a few % of it). Otherwise Welch segments of ``segment_s`` (default: a quarter of
    the record, at most 40 s), Hann windows, half overlap."""
    factor = max(int(round(1.0 / (rate_hz * data.dt))), 1)
    fs = 1.0 / (data.dt * factor)
    y, u = _down(data.y, factor), _down(data.u, factor)
    r = _down(data.r, factor) if data.r is not None else None
    seconds = len(y) / fs
    window, overlap = "hann", None
    skip = max(int(np.ceil(transient_s / period_s - 1e-9)), 1) if period_s else 0
    if period_s is not None and seconds >= (skip + 1) * period_s - 1.0 / fs:
        nper = int(round(period_s * fs))
        y, u = y[skip * nper:], u[skip * nper:]
        r = r[skip * nper:] if r is not None else None
        window, overlap = "boxcar", 0
    else:
        nper = int(fs * (segment_s or min(seconds / 4.0, 40.0)))
    nper = max(min(nper, len(y)), 16)
    spectra = {"nperseg": nper, "window": window, "noverlap": overlap}
    if r is not None and np.ptp(r) > 0.0:
        f, s_ry = csd(r, y, fs, **spectra)
        _, s_ru = csd(r, u, fs, **spectra)
        _, s_rr = welch(r, fs, **spectra)
        _, coh = coherence(r, y, fs, **spectra)
        return _excited(f, s_ry / s_ru, coh, s_rr, "joint input-output")
    f, s_uy = csd(u, y, fs, **spectra)
    _, s_uu = welch(u, fs, **spectra)
    _, coh = coherence(u, y, fs, **spectra)
    return _excited(f, s_uy / s_uu, coh, s_uu, "H1")


def period_of(signal: Excitation) -> float | None:
    """The period [s] of an experiment's signal, if it is periodic (a multisine, a PRBS)."""
    if isinstance(signal, Multisine):
        return signal.period_s
    if isinstance(signal, PRBS):
        return len(signal.bits) * signal.bit_s
    return None


def _excited(f, g, coh, power, method) -> Response:
    keep = power > EXCITED * np.max(power)
    keep[0] = False  # the mean was removed
    return Response(f[keep], g[keep], coh[keep], method)


def model(params: JointParams, f: np.ndarray) -> np.ndarray:
    """[2-50]: K_mdl L A_H K_ep / ((J s^2 + D s + K)(T_ep s + 1)) e^{-T_dly s} [deg/V] at f [Hz],
    friction aside."""
    s = 2j * np.pi * np.asarray(f)
    gain = params.K_mdl * params.L * params.area_head * K_EP
    return gain / ((params.J * s * s + params.D * s + params.K) * (params.T_ep * s + 1.0)) * np.exp(-params.T_dly * s)
