"""Distributed-force identification from the array pressure sensor (rig-facts §3): the
estimator the daemon runs, a frame at a time, with the contact's 1-sigma uncertainty.

The paper nests a spatial fit in each frame inside a temporal recursive least squares with
forgetting. Read literally (controllers.contact_paper), its layers hold constant parameters,
so they lag a contact that grows or shrinks, and they estimate the geometry and
[ln p_max, beta] apart, so beta takes on two to three times any geometry error (more on a
contact a few taxels across, where a larger contact with a larger beta reads nearly alike).
This estimator keeps the nesting and changes what the outer layer carries
(**interpretation**, chosen on simulated impacts; docs/estimation.md has the comparison):

- **inner, spatial** (each frame): the neighbouring-response region and its ring of
  untouched neighbours (controllers.contact_model); the pressure model over them, linearised
  at the prediction: one Gauss-Newton row per taxel, weighted by the sensor's noise (its
  +-0.5 % FS read as even noise, sigma = FS / 200 / sqrt 3);
- **outer, temporal**: recursive least squares in information form with forgetting on all
  six parameters *and their rates*, so a moving, growing or shrinking contact is followed
  without lag. The parameters are s = [cx, cy, a^2, b^2, (p_max / 1e5 Pa)^2, beta] [mm, mm^2,
  -]: by Hertz's scaling the contact's area and its peak pressure squared grow with the
  indentation, so in these a contact's course is nearly a straight line over the memory.
  Each frame (dk frame periods after the last):

      predict   s <- s + dk s',   N <- L (F^-T N F^-1) L      (F: s += dk s'; L: forgetting)
      correct   (s, s') <- (s, s') + (N + J^T J / sigma^2 + P)^-1 (J^T e / sigma^2 - P_beta (beta - 0.5))
                N <- N + J^T J / sigma^2

  with e the frame's residual at the prediction and J its Jacobian in s. The forgetting
  L = exp(-T / memory) per frame period T keeps a memory of ``memory_s`` for the geometry and
  p_max (4 ms: 16 frames at 4 kHz) and ``beta_memory_s`` for beta (8 ms), whose course is
  slower, whatever the frame rate. P holds what is known before the data: beta near Hertz's
  0.5 (1 sigma 0.3), which matters only while the contact is too small to say, and how fast
  the rates may change from frame to frame (a random walk: relative growth 120 /s, beta 4 /s,
  at 4 kHz), which keeps a rate from running along the few-taxel ambiguity.

At first touch (8 taxels active) a quadric fit of the taxels gives the geometry and a few
Gauss-Newton steps of the pressure model refine it with beta held at 0.5; the rates start at
0. A track whose model no longer explains the frames (the residual's mean square over
``LOST_CHI2`` times the noise's, its RMS over 3 times, for ``LOST_FRAMES`` frames in a row: a
second impact, a slip) starts again from the frame, as does a track the reader left for more
than ``STALE_MEMORIES`` memories (a stalled sensor process): what it knew is forgotten
(weight under e^-8) and its straight-line prediction that far on is no place to linearise a
single step at (simulated impacts: sigma-true up to 32 ms gaps, up to 67 sigma off after 100 ms
ones). The inverse of the information gives each
parameter's 1 sigma; sigma is the data sheet's noise, or more when the residuals of tracked
frames say so (a slow average), so a noisier pad widens the sigmas instead of making them lie.
"""
from __future__ import annotations

import math

import numpy as np

from controllers.contact_model import (
    MM,
    ContactEstimate,
    SensingGrid,
    contact_region,
    dilate,
    model_jacobian,
    quadric_geometry,
)
from hal.taxel_array import ACCURACY_PA

NOISE_PA = ACCURACY_PA / math.sqrt(3.0)  # the sensor's +-0.5 % FS as even noise: its standard deviation
NOISE_MEMORY_FRAMES = 1000.0  # the noise's estimate from the residuals: a slow average over tracked frames
PRESSURE_SCALE_PA = 1e5
MEMORY_S = 0.004  # centre, a, b, p_max and their rates; chosen on simulated impacts
BETA_MEMORY_S = 0.008  # beta and its rate
BETA_PRIOR = (0.5, 0.3)  # Hertz's beta, and 1 sigma of how far a contact may be from it
GROWTH_STEP_PER_S = 120.0  # 1 sigma of a frame's change in a relative rate (a^2, b^2, p_max^2, centre / b) at 4 kHz [1/s]
BETA_RATE_STEP_PER_S = 4.0  # likewise for beta's rate [1/s]
NOMINAL_FRAME_HZ = 4000.0  # the sensor's rate, where the steps above were chosen
LOST_CHI2, LOST_FRAMES = 9.0, 3
STALE_MEMORIES = 8.0  # a gap longer than this many (geometry) memories starts the track again
START_STEPS = 6  # Gauss-Newton steps on the first frame
LEVELS = 6  # s; the rates s' follow
BETA = 5


def to_levels(shape: np.ndarray) -> np.ndarray:
    """(cx, cy, a, b [mm], ln p_max, beta) -> s = (cx, cy, a^2, b^2, (p_max / 1e5 Pa)^2, beta)."""
    cx, cy, a, b, ln_pm, beta = shape
    return np.array([cx, cy, a * a, b * b, math.exp(2.0 * ln_pm) / PRESSURE_SCALE_PA ** 2, beta])


def to_shape(levels: np.ndarray) -> np.ndarray:
    cx, cy, area_a, area_b, pressure, beta = levels
    return np.array([cx, cy, math.sqrt(area_a), math.sqrt(area_b),
                     0.5 * math.log(pressure) + math.log(PRESSURE_SCALE_PA), beta])


def levels_model(levels: np.ndarray, px: np.ndarray, py: np.ndarray):
    """The model [Pa] at sensing points (px, py) [mm] and its Jacobian in s (chain rule on
    controllers.contact_model.model_jacobian)."""
    shape = to_shape(levels)
    model, jac = model_jacobian(shape, px, py)
    jac[:, 2] /= 2.0 * shape[2]
    jac[:, 3] /= 2.0 * shape[3]
    jac[:, 4] /= 2.0 * levels[4]
    return model, jac


def _in_domain(levels: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(levels)) and levels[2] > 0.01 and levels[3] > 0.01 and levels[4] > 1e-8
                and 0.05 <= levels[BETA] <= 5.0)


class ContactEstimator:
    """Frames [Pa] in, :class:`ContactEstimate` out (see the module). ``memory_s`` and
    ``beta_memory_s``: the memories [s]; ``frame_hz``: the sensor's frame rate, which turns
    them and the rates' steps into per-frame terms; ``update``'s ``frames`` says how many frame
    periods passed since the last call (a reader that fell behind skips frames)."""

    def __init__(self, memory_s: float = MEMORY_S, beta_memory_s: float = BETA_MEMORY_S,
                 frame_hz: float = NOMINAL_FRAME_HZ):
        if not frame_hz > 0:
            raise ValueError(f"frame rate {frame_hz} Hz: must be positive")
        for name, value in (("memory_s", memory_s), ("beta_memory_s", beta_memory_s)):
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name} {value}: must be within (0, 1] s")
        self.forgetting = np.exp(-1.0 / (frame_hz * np.array([memory_s] * (LEVELS - 1) + [beta_memory_s])))
        self.frame_hz = frame_hz
        self.stale_frames = STALE_MEMORIES * memory_s * frame_hz
        self.grid = SensingGrid()
        self.noise_var = NOISE_PA ** 2  # [Pa^2]: the sensor's, or more when its residuals say so
        self.reset()

    def reset(self) -> None:
        self.state = None  # (s, s') [mm, mm^2, -; per frame], or None: no contact tracked
        self.info = None  # N, 12 x 12, in 1 / (s, s')^2
        self.lost = 0
        self.track_frames = 0  # frames this track has estimated

    def update(self, frame_pa: np.ndarray, frames: int = 1) -> ContactEstimate | None:
        """One frame [Pa] (16 x 16, NaN where dead) -> the contact, or None (no contact)."""
        if frames < 1:
            raise ValueError(f"frames {frames}: at least one frame period since the last update")
        region = contact_region(frame_pa)
        if region is None or frames > self.stale_frames:
            self.reset()
        if region is None:
            return None
        ring = dilate(region) & ~np.isnan(frame_pa)
        p, px, py = frame_pa[ring], self.grid.px[ring], self.grid.py[ring]
        if self.state is None:
            if not self._start(region, frame_pa, px, py, p):
                return None
            frames = 0
        stepped = self._step(px, py, p, frames)
        if stepped is None:
            self.reset()  # no cap shape: the model does not hold this frame
            return None
        chi2, residual = stepped
        self.lost = self.lost + 1 if chi2 > LOST_CHI2 else 0
        if self.lost >= LOST_FRAMES:  # the track no longer explains the frames: start again from this one
            self.reset()
            return self.update(frame_pa)
        self.track_frames += 1
        return self._estimate(len(p), residual)

    def _start(self, region, frame_pa, px, py, p) -> bool:
        """The first frame's geometry: the quadric, then Gauss-Newton steps with beta at 0.5."""
        first = quadric_geometry(self.grid.x[region], self.grid.y[region], frame_pa[region])
        if first is None:
            return False
        levels = to_levels(np.array([*first, math.log(float(frame_pa[region].max())), BETA_PRIOR[0]]))
        cost, previous = None, levels
        for _ in range(START_STEPS):
            model, jac = levels_model(levels, px, py)
            error = p - model
            if cost is not None and float(error @ error) >= cost:
                levels = previous  # the last step made it worse: keep the one before
                break
            cost, previous = float(error @ error), levels
            jac = jac[:, :BETA]
            normal = jac.T @ jac
            normal[np.diag_indices(BETA)] *= 1.0 + 1e-2
            candidate = levels.copy()
            candidate[:BETA] += np.linalg.solve(normal, jac.T @ error)
            if not _in_domain(candidate):
                break
            levels = candidate
        self.state = np.concatenate([levels, np.zeros(LEVELS)])
        self.info = np.zeros((2 * LEVELS, 2 * LEVELS))
        scale = np.array([math.sqrt(levels[3]), math.sqrt(levels[3]), levels[2], levels[3], levels[4], 1.0])
        steps = np.append(GROWTH_STEP_PER_S * scale[:BETA], BETA_RATE_STEP_PER_S)
        steps *= math.sqrt(NOMINAL_FRAME_HZ / self.frame_hz) / self.frame_hz  # per frame, a random walk's
        self.rate_step_info = 1.0 / steps ** 2
        return True

    def _prior(self, frames: int) -> np.ndarray:
        """What is known before this frame's data, as information on (s, s'): beta's level
        near Hertz's, and each rate's change over ``frames`` frame periods (a random walk)."""
        prior = np.zeros(2 * LEVELS)
        prior[BETA] = 1.0 / BETA_PRIOR[1] ** 2
        prior[LEVELS:] = self.rate_step_info / max(frames, 1)
        return prior

    def _step(self, px, py, p, frames: int) -> tuple[float, float] | None:
        """Predict ``frames`` frame periods on and correct with this frame: the residual at
        the prediction as chi^2 per taxel (1: as the noise alone) and relative to the
        pressures (its RMS); None when the step leaves the model's domain."""
        inverse_move = np.eye(2 * LEVELS)
        inverse_move[:LEVELS, LEVELS:] = -frames * np.eye(LEVELS)
        kept = np.sqrt(np.tile(self.forgetting, 2) ** frames)
        predicted = self.state.copy()
        predicted[:LEVELS] += frames * self.state[LEVELS:]
        if not _in_domain(predicted[:LEVELS]):
            return None
        info = (inverse_move.T @ self.info @ inverse_move) * kept[:, None] * kept[None, :]
        model, jac = levels_model(predicted[:LEVELS], px, py)
        error = p - model
        info[:LEVELS, :LEVELS] += jac.T @ jac / self.noise_var
        prior = self._prior(frames)
        system = info.copy()
        system[np.diag_indices(2 * LEVELS)] += prior
        system[np.diag_indices(LEVELS)] *= 1.0 + 1e-3  # a touch of Levenberg damping along the few-taxel ambiguity
        rhs = np.zeros(2 * LEVELS)
        rhs[:LEVELS] = jac.T @ error / self.noise_var
        rhs[BETA] -= prior[BETA] * (predicted[BETA] - BETA_PRIOR[0])
        covariance = np.linalg.inv(system)  # of (s, s') after this frame: the step, and the sigmas
        corrected = predicted + covariance @ rhs
        if not _in_domain(corrected[:LEVELS]):
            return None
        self.state, self.info, self.covariance = corrected, info, covariance
        squares = float(error @ error)
        chi2 = squares / (len(p) * self.noise_var)
        if chi2 < LOST_CHI2:  # a noisier sensor than its data sheet's: its sigmas widen to match
            mean_square = squares / len(p)
            self.noise_var = max(self.noise_var + (mean_square - self.noise_var) / NOISE_MEMORY_FRAMES, NOISE_PA ** 2)
        return chi2, math.sqrt(squares / float(p @ p))

    def _estimate(self, taxels: int, residual: float) -> ContactEstimate:
        """The state as a contact [m, Pa], each parameter's 1 sigma from the step's covariance
        (the rates marginalised), the force's through its gradient."""
        levels = self.state[:LEVELS]
        cx, cy, a, b, ln_pm, beta = to_shape(levels)
        p_max = math.exp(ln_pm)
        # s -> (cx, cy, a, b, p_max, beta): a = sqrt(a^2), p_max = 1e5 sqrt(s_4)
        to_params = np.array([1.0, 1.0, 0.5 / a, 0.5 / b, 0.5 * p_max / levels[4], 1.0])
        params_cov = self.covariance[:LEVELS, :LEVELS] * to_params[:, None] * to_params[None, :]
        sd = np.sqrt(np.maximum(np.diag(params_cov), 0.0))
        force = math.pi * a * b * p_max / (beta + 1.0)  # [mm^2 Pa]; its gradient in the parameters:
        grad = np.array([0.0, 0.0, force / a, force / b, force / p_max, -force / (beta + 1.0)])
        force_sd = math.sqrt(max(float(grad @ params_cov @ grad), 0.0)) / MM ** 2
        return ContactEstimate(cx / MM, cy / MM, a / MM, b / MM, p_max, beta, taxels, residual,
                               sd[0] / MM, sd[1] / MM, sd[2] / MM, sd[3] / MM, sd[4], sd[5], force_sd,
                               self.track_frames)
