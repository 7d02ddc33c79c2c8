"""Excitation signals for identification experiments (rig-facts §1 "Experiments"): a
log-swept chirp and a PRBS (maximum-length sequence), added to one joint's reference while
the others hold, so the loop's frequency response can be measured from a recording.

Log chirp from f0 to f1 [Hz] over T [s], k = f1 / f0 (frequency f(t) = f0 k^(t/T)):

    r(t) = A sin(phi(t)),   phi(t) = 2 pi f0 T (k^(t/T) - 1) / ln k,
    r' = A cos(phi) 2 pi f(t),   r'' = -A sin(phi) (2 pi f)^2 + A cos(phi) 2 pi f ln(k) / T,

the same phase as scipy.signal.chirp(method="logarithmic"). PRBS: scipy.signal.max_len_seq
of the given order, each bit held ``bit_s`` [s], r = +-A, repeated ``periods`` times; its
spectrum is flat up to about 1 / (2 bit_s) [Hz]. Angles in rad, time in s.
"""
from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Sequence

from scipy.signal import max_len_seq

from controllers.trajectory import Sample, Trajectory


class Excitation(Trajectory):
    """Base angles [rad] held, one joint's reference offset by a signal."""

    def __init__(self, base: Sequence[float], joint: int, duration: float):
        self.base, self.joint, self.duration = list(base), joint, duration
        self._zeros = [0.0] * len(base)

    @abstractmethod
    def offset(self, t: float) -> tuple[float, float, float]:
        """The signal, its rate and its acceleration at t [rad, rad/s, rad/s^2]."""

    def sample(self, t: float) -> Sample:
        r, w, a = self.offset(min(max(t, 0.0), self.duration))
        q, v, acc = list(self.base), list(self._zeros), list(self._zeros)
        q[self.joint] += r
        v[self.joint], acc[self.joint] = w, a
        return q, v, acc


class LogChirp(Excitation):
    def __init__(self, base, joint: int, amplitude: float, f0: float, f1: float, duration: float):
        if not 0 < f0 < f1:
            raise ValueError(f"a chirp needs 0 < f0 < f1, got {f0} and {f1} Hz")
        super().__init__(base, joint, duration)
        self.amplitude, self.f0, self.f1 = amplitude, f0, f1
        self._ln_k = math.log(f1 / f0)

    def offset(self, t: float) -> tuple[float, float, float]:
        if t >= self.duration:
            return 0.0, 0.0, 0.0
        T, ln_k, A = self.duration, self._ln_k, self.amplitude
        growth = math.exp(ln_k * t / T)
        phase = 2 * math.pi * self.f0 * T * (growth - 1.0) / ln_k
        omega = 2 * math.pi * self.f0 * growth  # [rad/s]
        s, c = math.sin(phase), math.cos(phase)
        return A * s, A * c * omega, -A * s * omega * omega + A * c * omega * ln_k / T


class PRBS(Excitation):
    def __init__(self, base, joint: int, amplitude: float, order: int, bit_s: float, periods: int = 1):
        bits = max_len_seq(order)[0]
        super().__init__(base, joint, len(bits) * bit_s * periods)
        self.levels = [amplitude if b else -amplitude for b in bits]
        self.bit_s = bit_s

    def offset(self, t: float) -> tuple[float, float, float]:
        if t >= self.duration:
            return 0.0, 0.0, 0.0
        return self.levels[int(t / self.bit_s) % len(self.levels)], 0.0, 0.0
