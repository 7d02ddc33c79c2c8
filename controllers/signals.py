"""Excitation signals for identification experiments (rig-facts §1 "Experiments"): a
log-swept chirp and a PRBS (maximum-length sequence), added to one joint's reference while
the others hold, so the loop's frequency response can be measured from a recording.

Log chirp from f0 to f1 [Hz] over T [s], k = f1 / f0 (frequency f(t) = f0 k^(t/T)):

    r(t) = A sin(phi(t)),   phi(t) = 2 pi f0 T (k^(t/T) - 1) / ln k,
    r' = A cos(phi) 2 pi f(t),   r'' = -A sin(phi) (2 pi f)^2 + A cos(phi) 2 pi f ln(k) / T,

the same phase as scipy.signal.chirp(method="logarithmic"). PRBS: scipy.signal.max_len_seq
of the given order, each bit held ``bit_s`` [s], r = +-A, repeated ``periods`` times; its
spectrum is flat up to about 1 / (2 bit_s) [Hz]. Angles in rad, time in s.

Neither signal's demands fall with its duration, so they are not time-scaled shapes: the
planner checks them where they are hardest (:meth:`Excitation.profile`), the chirp over a grid
of its frequencies and phases, the PRBS at its two levels, never by walking an hour of signal.
"""
from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Sequence

import numpy as np

from controllers.profile import Profile
from controllers.trajectory import Sample, Trajectory

CHIRP_FREQUENCIES = 256  # profile grid of a chirp: log-spaced frequencies ...
CHIRP_PHASES = 32  # ... times phases over one period


class Excitation(Trajectory):
    """Base angles [rad] held, one joint's reference offset by a signal."""

    scalable = False
    definition: dict | None = None  # the request's settings, for the recording (set by the planner)

    def __init__(self, base: Sequence[float], joint: int, duration: float):
        self.base, self.joint, self.duration = list(base), joint, duration
        self._zeros = [0.0] * len(base)

    @property
    def peak(self) -> float:
        """The largest |offset| the signal reaches."""
        return self.amplitude

    @abstractmethod
    def offset(self, t: float) -> tuple[float, float, float]:
        """The signal, its rate and its acceleration at t [rad, rad/s, rad/s^2]."""

    @abstractmethod
    def series(self, t: np.ndarray) -> np.ndarray:
        """The signal at many times at once (0 after its end), for planning: what
        :meth:`offset` gives one at a time."""

    def sample(self, t: float) -> Sample:
        r, w, a = self.offset(min(max(t, 0.0), self.duration))
        q, v, acc = list(self.base), list(self._zeros), list(self._zeros)
        q[self.joint] += r
        v[self.joint], acc[self.joint] = w, a
        return q, v, acc

    def _profile(self, t, r, w, a) -> Profile:
        """The profile of offsets r, w, a (arrays) at times t on the signal's joint."""
        q = np.tile(np.asarray(self.base, dtype=float), (len(t), 1))
        rates, accels = np.zeros_like(q), np.zeros_like(q)
        q[:, self.joint] += r
        rates[:, self.joint], accels[:, self.joint] = w, a
        return Profile(np.asarray(t, dtype=float), q, rates, accels)


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

    def series(self, t: np.ndarray) -> np.ndarray:
        T = self.duration
        phase = 2 * np.pi * self.f0 * T * (np.exp(self._ln_k * t / T) - 1.0) / self._ln_k
        return np.where(t < T, self.amplitude * np.sin(phase), 0.0)

    def profile(self, points: int = 0) -> Profile:
        """Every phase at each of a grid of the sweep's frequencies: the chirp passes through
        all of them near that frequency, so its worst demand is on this grid."""
        T, ln_k, A = self.duration, self._ln_k, self.amplitude
        f = np.geomspace(self.f0, self.f1, CHIRP_FREQUENCIES)[:, None]
        phase = np.linspace(0.0, 2 * np.pi, CHIRP_PHASES, endpoint=False)[None, :]
        omega, s, c = 2 * np.pi * f, np.sin(phase), np.cos(phase)
        shape = (CHIRP_FREQUENCIES, CHIRP_PHASES)
        t = np.broadcast_to(T * np.log(f / self.f0) / ln_k, shape)
        return self._profile(t.ravel(), np.broadcast_to(A * s, shape).ravel(), (A * c * omega).ravel(),
                             (-A * s * omega ** 2 + A * c * omega * ln_k / T).ravel())


class PRBS(Excitation):
    def __init__(self, base, joint: int, amplitude: float, order: int, bit_s: float, periods: int = 1):
        from scipy.signal import max_len_seq  # here, off the loop: at module level it cost
        # the loop's process 1-2 s of every daemon start
        self.bits = max_len_seq(order)[0].astype(np.uint8).tobytes()  # compact: one byte a bit
        super().__init__(base, joint, len(self.bits) * bit_s * periods)
        self.amplitude, self.bit_s = amplitude, bit_s

    def offset(self, t: float) -> tuple[float, float, float]:
        if t >= self.duration:
            return 0.0, 0.0, 0.0
        return (self.amplitude if self.bits[int(t / self.bit_s) % len(self.bits)] else -self.amplitude), 0.0, 0.0

    def series(self, t: np.ndarray) -> np.ndarray:
        bits = np.frombuffer(self.bits, dtype=np.uint8)
        level = np.where(bits[(t / self.bit_s).astype(np.int64) % len(bits)] == 1, self.amplitude, -self.amplitude)
        return np.where(t < self.duration, level, 0.0)

    def profile(self, points: int = 0) -> Profile:
        """Its two levels (it steps between them: the rig must hold each)."""
        zeros = np.zeros(2)
        return self._profile(zeros, np.array([self.amplitude, -self.amplitude]), zeros, zeros)


class Multisine(Excitation):
    """Periodic: up to ``components`` harmonics of 1 / ``period_s``, log-spaced over f0..f1 [Hz]
    (repeated harmonics merged), of equal amplitudes scaled so that the peak is A, with
    Schroeder's phases phi_k = -pi k (k - 1) / count, which keep the crest factor low;
    ``periods`` periods. A whole number of periods has no leakage in a frequency response.
    Evaluated in closed form: a bounded number of sines a cycle (MAX_COMPONENTS)."""

    MAX_COMPONENTS = 32

    def __init__(self, base, joint: int, amplitude: float, f0: float, f1: float, components: int, period_s: float,
                 periods: int = 1):
        if not 0 < f0 < f1:
            raise ValueError(f"a multisine needs 0 < f0 < f1, got {f0} and {f1} Hz")
        if not 1 <= components <= self.MAX_COMPONENTS:
            raise ValueError(f"a multisine has 1-{self.MAX_COMPONENTS} components, got {components}")
        harmonics = sorted({max(int(round(h)), 1) for h in np.geomspace(f0 * period_s, f1 * period_s, components)})
        self.omegas = [2 * math.pi * h / period_s for h in harmonics]
        count = len(harmonics)
        self.phases = [-math.pi * k * (k - 1) / count for k in range(1, count + 1)]
        self.period_s = period_s
        super().__init__(base, joint, period_s * periods)
        self.a_k = 1.0
        self.a_k = amplitude / float(np.max(np.abs(self.series(np.arange(0.0, period_s, 1e-3)))))
        self.amplitude = amplitude

    def offset(self, t: float) -> tuple[float, float, float]:
        if t >= self.duration:
            return 0.0, 0.0, 0.0
        r = w = a = 0.0
        for om, ph in zip(self.omegas, self.phases):
            s, c = math.sin(om * t + ph), math.cos(om * t + ph)
            r += s
            w += c * om
            a -= s * om * om
        return self.a_k * r, self.a_k * w, self.a_k * a

    def series(self, t: np.ndarray) -> np.ndarray:
        total = np.zeros_like(t, dtype=float)
        for om, ph in zip(self.omegas, self.phases):
            total += np.sin(om * t + ph)
        return np.where(t < self.duration, self.a_k * total, 0.0)

    def profile(self, points: int = 0) -> Profile:
        """Its worst demands: its peak, and every term at its peak at once bounding the rates."""
        peak = self.amplitude
        rate = self.a_k * sum(self.omegas)
        accel = self.a_k * sum(om * om for om in self.omegas)
        zeros = np.zeros(2)
        return self._profile(zeros, np.array([peak, -peak]), np.array([rate, -rate]), np.array([accel, -accel]))


class Levels(Excitation):
    """Steps between levels (each held ``hold_s``), then back to zero: a staircase or a
    step test. Looked up by bisection (at most MAX_LEVELS)."""

    MAX_LEVELS = 256

    def __init__(self, base, joint: int, levels: Sequence[float], hold_s: float):
        if not 1 <= len(levels) <= self.MAX_LEVELS:
            raise ValueError(f"1-{self.MAX_LEVELS} levels, got {len(levels)}")
        super().__init__(base, joint, len(levels) * hold_s)
        self.levels, self.hold_s = [float(v) for v in levels], hold_s
        self.amplitude = max(abs(v) for v in self.levels)

    def offset(self, t: float) -> tuple[float, float, float]:
        if t >= self.duration:
            return 0.0, 0.0, 0.0
        return self.levels[min(int(t / self.hold_s), len(self.levels) - 1)], 0.0, 0.0

    def series(self, t: np.ndarray) -> np.ndarray:
        index = np.minimum((t / self.hold_s).astype(np.int64), len(self.levels) - 1)
        return np.where(t < self.duration, np.asarray(self.levels)[index], 0.0)

    def profile(self, points: int = 0) -> Profile:
        zeros = np.zeros(len(self.levels))
        return self._profile(zeros, np.array(self.levels), zeros, zeros)
